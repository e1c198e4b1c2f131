"""``wfjax geometry``: a flat's profile deviation and rigid wheel-centre trajectory (Fig. 5)."""

from __future__ import annotations

import numpy as np

from .. import geometry
from ..params import Flat, new_flat_length
from ._common import add_out_argument, prepare_out, save_figure, write_atomic, write_json

HELP = "profile deviation and wheel-centre trajectory of a flat (CSV, JSON, Fig. 5 PNG)"


def add_flat_arguments(parser, default_kind="rounded", default_depth_mm=0.9,
                       default_length_mm=100.0) -> None:
    """``--flat``, ``--depth-mm``, ``--length-mm``, ``--wheel-radius-m`` shared by subcommands."""
    parser.add_argument("--flat", choices=["new", "rounded"], default=default_kind,
                        help=f"flat kind (default: {default_kind})")
    parser.add_argument("--depth-mm", type=float, default=default_depth_mm,
                        help=f"flat depth d in mm (default: {default_depth_mm})")
    parser.add_argument("--length-mm", type=float, default=default_length_mm,
                        help="rounded flat length l in mm (default: %(default)s; ignored for new)")
    parser.add_argument("--wheel-radius-m", type=float, default=0.45,
                        help="wheel radius R_W in m (default: 0.45)")


def flat_from_args(args, kind=None, depth_mm=None) -> Flat:
    """Build the :class:`Flat` named by the command-line options (validated)."""
    kind = kind or args.flat
    depth = (depth_mm if depth_mm is not None else args.depth_mm) * 1e-3
    if kind == "new":
        return Flat.new(depth, args.wheel_radius_m)
    return Flat.rounded(depth, args.length_mm * 1e-3, args.wheel_radius_m)


def add_arguments(parser) -> None:
    add_flat_arguments(parser)
    add_out_argument(parser, "out/geometry")


def run(args) -> int:
    from ..plotting import flat_inputs_figure

    flat = flat_from_args(args)
    out = prepare_out(args.out)
    half = 1.2 * flat.half_extent
    x = np.linspace(-half, half, 481)
    z = np.asarray(geometry.profile_deviation(flat, x))
    traj = np.asarray(geometry.centre_trajectory(flat, x))
    rows = "\n".join(f"{a * 1e3:.4f},{b * 1e3:.6f},{c * 1e3:.6f}"
                     for a, b, c in zip(x, z, traj, strict=True))
    write_atomic(out / "geometry.csv",
                 "x_mm,profile_deviation_mm,centre_trajectory_mm\n" + rows + "\n")
    l0 = new_flat_length(flat.depth, flat.wheel_radius)
    summary = {
        "flat": flat.kind,
        "depth_mm": float(flat.depth) * 1e3,
        "length_mm": float(flat.length) * 1e3,
        "new_flat_length_l0_mm": float(l0) * 1e3,
        "wheel_radius_m": float(flat.wheel_radius),
        "trajectory_min_mm": float(traj.min()) * 1e3,
        "trajectory_width_mm": float(np.ptp(x[traj < 0])) * 1e3 if np.any(traj < 0) else 0.0,
    }
    write_json(out / "geometry.json", summary)
    save_figure(flat_inputs_figure({f"{flat.kind} flat, d = {args.depth_mm:g} mm": flat}),
                out / "geometry.png")
    print(f"{flat.kind} flat: depth {summary['depth_mm']:.3f} mm, length "
          f"{summary['length_mm']:.1f} mm (l0 = {summary['new_flat_length_l0_mm']:.1f} mm); "
          f"wheel-centre drop {-summary['trajectory_min_mm']:.3f} mm over "
          f"{summary['trajectory_width_mm']:.1f} mm")
    print(f"wrote {out}/geometry.csv, geometry.json, geometry.png")
    return 0

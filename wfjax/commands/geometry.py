"""``wfjax geometry``: a flat's profile deviation and rigid wheel-centre trajectory (Fig. 5)."""

from __future__ import annotations

import numpy as np

from ._common import (
    prepare_out,
    resolve_case,
    save_figure,
    write_atomic,
    write_summary,
)

HELP = "profile deviation and wheel-centre trajectory of a flat (CSV, JSON, Fig. 5 PNG)"

def run(args) -> int:
    from ..model import geometry
    from ..params import new_flat_length
    from ..plotting import flat_inputs_figure

    case = resolve_case(args, "geometry")
    flat = case.flat()
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
    write_summary(out / "geometry.json", summary, case,
                  {"profile_csv": case.get("flat.profile_csv")})
    label = f"{flat.kind} flat, d = {summary['depth_mm']:g} mm"
    save_figure(flat_inputs_figure({label: flat}), out / "geometry.png")
    print(f"{flat.kind} flat: depth {summary['depth_mm']:.3f} mm, length "
          f"{summary['length_mm']:.1f} mm (l0 = {summary['new_flat_length_l0_mm']:.1f} mm); "
          f"wheel-centre drop {-summary['trajectory_min_mm']:.3f} mm over "
          f"{summary['trajectory_width_mm']:.1f} mm")
    print(f"wrote {out}/geometry.csv, geometry.json, geometry.png, case.toml")
    return 0

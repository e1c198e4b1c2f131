"""``wfjax sweep``: max/min contact force against speed over impact positions (Fig. 7)."""

from __future__ import annotations

import os
import time

import numpy as np

from ..params import Material, SimConfig, Track, Wheel
from ._common import add_out_argument, prepare_out, save_figure, write_atomic, write_json
from .geometry import flat_from_args

HELP = "speed sweep of max/min contact force over impact positions (default: Fig. 7, 3D contact)"


def parse_range_kmh(text: str) -> np.ndarray:
    """Speeds [m/s] from ``"start:stop:step"`` (inclusive, km/h) or ``"v1,v2,..."`` (km/h)."""
    try:
        if ":" in text:
            start, stop, step = (float(p) for p in text.split(":"))
            if step <= 0 or stop < start:
                raise ValueError
            values = np.arange(start, stop + 0.5 * step, step)
        else:
            values = np.array([float(p) for p in text.split(",")])
    except ValueError:
        raise ValueError(
            f"--speeds-kmh must be 'start:stop:step' or 'v1,v2,...' in km/h, got {text!r}"
        ) from None
    if values.size == 0 or np.any(values <= 0) or np.any(values > 540) or not np.all(
            np.isfinite(values)):
        raise ValueError(f"--speeds-kmh must lie in (0, 540] km/h, got {text!r}")
    return values / 3.6


def add_model_arguments(parser) -> None:
    """Contact model and track options shared by sweep and simulate."""
    parser.add_argument("--contact", default="3d",
                        choices=["3d", "2d", "hertz-trajectory", "hertz-profile"],
                        help="contact model (default: 3d)")
    parser.add_argument("--rail-head-radius-m", type=float, default=0.30,
                        help="transverse rail head radius R_R in m (default 0.30; the paper's "
                             "model comparison uses 0.45)")


def model_from_args(args):
    """(wheel, track, material, config) from the shared options."""
    return Wheel(), Track(rail_head_radius=args.rail_head_radius_m), Material(), SimConfig()


def add_arguments(parser) -> None:
    parser.add_argument("--flat", choices=["both", "new", "rounded"], default="both",
                        help="flat kind(s) (default: both, as in Fig. 7)")
    parser.add_argument("--depth-mm", type=float, default=0.9, help="flat depth d in mm (0.9)")
    parser.add_argument("--length-mm", type=float, default=100.0,
                        help="rounded flat length l in mm (default 100)")
    parser.add_argument("--wheel-radius-m", type=float, default=0.45, help=argparse_hide())
    parser.add_argument("--speeds-kmh", default="20:300:10",
                        help="speeds in km/h, 'start:stop:step' or 'v1,v2' (default 20:300:10)")
    parser.add_argument("--positions", type=int, default=10,
                        help="impact positions evenly covering one sleeper bay (default 10)")
    add_model_arguments(parser)
    parser.add_argument("--precision", choices=["float64", "float32"], default="float64",
                        help="floating-point precision of the computation (default float64; "
                             "float32 for GPUs, see benchmarks/README.md 'Precision')")
    add_out_argument(parser, "out/sweep")


def argparse_hide():
    import argparse

    return argparse.SUPPRESS


def set_precision(precision: str) -> None:
    """Select float64 or float32 for everything computed afterwards (the one place the CLI does).

    Sets ``WFJAX_PRECISION`` (read by ``import wfjax`` in child processes) and
    ``jax_enable_x64`` (this process). Must run before any array of the computation is made;
    ``run`` calls it first.
    """
    import jax

    if precision not in ("float64", "float32"):
        raise ValueError(f"--precision must be float64 or float32, got {precision!r}")
    os.environ["WFJAX_PRECISION"] = precision
    jax.config.update("jax_enable_x64", precision == "float64")


def run(args) -> int:
    set_precision(getattr(args, "precision", "float64"))
    from ..plotting import sweep_figure
    from ..sweep import sweep

    speeds = parse_range_kmh(args.speeds_kmh)
    if args.positions < 1:
        raise ValueError(f"--positions must be >= 1, got {args.positions}")
    kinds = ["rounded", "new"] if args.flat == "both" else [args.flat]
    flats = [flat_from_args(args, kind=k) for k in kinds]
    wheel, track, material, config = model_from_args(args)
    out = prepare_out(args.out)
    print(f"wfjax sweep: {len(flats)} flat(s) x {speeds.size} speeds x {args.positions} "
          f"positions, {args.contact} contact, R_R = {args.rail_head_radius_m} m, "
          f"{getattr(args, 'precision', 'float64')}")
    t0 = time.perf_counter()
    result = sweep(flats, speeds, args.positions, contact=args.contact, wheel=wheel,
                   track=track, material=material, config=config)
    elapsed = time.perf_counter() - t0
    write_atomic(out / "sweep.csv", result.to_csv())
    result.save_npz(out / "sweep.npz")
    summary = result.summary()
    summary["wall_time_s"] = elapsed
    summary["precision"] = getattr(args, "precision", "float64")
    write_json(out / "sweep.json", summary)
    save_figure(sweep_figure(result), out / "sweep.png")
    for label, s in summary["flats"].items():
        loss = s["first_loss_of_contact_kmh"]
        loss_text = f"from {loss:.0f} km/h" if loss is not None else "none"
        print(f"  {label}: peak max force {s['peak_max_force_kN']:.1f} kN at "
              f"{s['at_speed_kmh']:.0f} km/h; loss of contact {loss_text}; spread over "
              f"positions up to {s['max_spread_over_positions_percent']:.1f} %")
    print(f"  {elapsed:.1f} s; wrote {out}/sweep.csv, sweep.json, sweep.npz, sweep.png")
    return 0

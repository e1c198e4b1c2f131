"""``wfjax sweep``: max/min contact force against speed over impact positions (Fig. 7).

Flats: one kind (or ``--flat both``: a rounded and a new flat) at one depth or a list of
depths (``--depths-mm 0.25:2:0.25``), with one length for all, one length per depth
(``--lengths-mm``) or a length rule (``--length-factor 1.76``: l = 1.76 l0), or a measured
profile (``--profile-csv``). All flats go to one :func:`wfjax.sweep` call and into one CSV,
JSON, NPZ and PNG (one curve per flat).
"""

from __future__ import annotations

import time

import numpy as np

from ._common import (
    ROUGHNESS_FLAGS,
    VEHICLE_FLAGS,
    add_case_arguments,
    add_out_argument,
    add_roughness_arguments,
    add_speed_arguments,
    add_vehicle_arguments,
    case_vehicle,
    check_finite,
    prepare_out,
    resolve_case,
    save_figure,
    write_atomic,
    write_summary,
)

HELP = "speed sweep of max/min contact force over impact positions (default: Fig. 7, 3D contact)"

MM = 1e-3
MODEL_FLAGS = {"contact": ("run.contact", 1.0),
               "rail_head_radius_m": ("track.rail_head_radius", 1.0),
               "wheel_radius_m": ("wheel.radius", 1.0),
               "precision": ("config.precision", 1.0)}
FLAT_FLAGS = {"flat": ("flat.kind", 1.0), "depth_mm": ("flat.depth", MM),
              "length_mm": ("flat.length", MM), "profile_csv": ("flat.profile_csv", 1.0),
              "profile_smoothing_mm": ("flat.profile_smoothing_mm", 1.0)}
FLAGS = {**MODEL_FLAGS, **FLAT_FLAGS, "length_factor": ("flat.length_factor", 1.0),
         "speeds_kmh": ("run.speeds_kmh", 1.0), "positions": ("run.impact_positions", 1.0),
         **VEHICLE_FLAGS, **ROUGHNESS_FLAGS}


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


def add_model_arguments(parser, contact_default: str = "3d", rail_head_default: float = 0.30,
                        choices=("3d", "2d", "hertz-trajectory", "hertz-profile")) -> None:
    """Contact model, rail head radius and precision (sweep, simulate, fit)."""
    parser.add_argument("--contact", choices=choices,
                        help=f"contact model (default: {contact_default})")
    parser.add_argument("--rail-head-radius-m", type=float,
                        help=f"transverse rail head radius R_R in m (default "
                             f"{rail_head_default:g}; the paper's model comparison uses 0.45)")
    parser.add_argument("--precision", choices=["float64", "float32"],
                        help="dtype of the time loop, SimConfig.precision (default: "
                             "WFJAX_PRECISION, else float64; float32 for GPUs, see "
                             "benchmarks/README.md)")


def add_profile_arguments(parser) -> None:
    """``--profile-csv`` and ``--profile-smoothing-mm`` (sweep, simulate, fit, geometry)."""
    parser.add_argument("--profile-csv", metavar="FILE",
                        help="measured flat profile, columns x_mm,z_mm (circumferential "
                             "coordinate and radial deviation in mm; docs/case_files.md); "
                             "implies --flat profile")
    parser.add_argument("--profile-smoothing-mm", type=float,
                        help="Gaussian smoothing of the profile, standard deviation in mm "
                             "(default 0: none)")


def add_arguments(parser) -> None:
    parser.add_argument("--flat", choices=["both", "new", "rounded", "profile"],
                        help="flat kind(s) (default: both, as in Fig. 7)")
    parser.add_argument("--depth-mm", "--depths-mm", dest="depth_mm", metavar="MM",
                        help="flat depth(s) d in mm: 0.9, 'a,b,c' or 'start:stop:step' "
                             "(default 0.9)")
    parser.add_argument("--length-mm", "--lengths-mm", dest="length_mm", metavar="MM",
                        help="rounded flat length(s) l in mm: one for all depths or one per "
                             "depth (default 100)")
    parser.add_argument("--length-factor", type=float,
                        help="rounded flat length l = factor x l0, l0 = sqrt(8 R d) (Fig. 8: "
                             "1.76); replaces --length-mm")
    add_profile_arguments(parser)
    parser.add_argument("--wheel-radius-m", type=float, help=argparse_hide())
    add_speed_arguments(parser, "20:300:10", 10)
    add_vehicle_arguments(parser)
    add_roughness_arguments(parser, monte_carlo=True)
    add_model_arguments(parser)
    add_case_arguments(parser)
    add_out_argument(parser, "out/sweep")


def argparse_hide():
    import argparse

    return argparse.SUPPRESS


def run(args) -> int:
    import importlib

    from .._parallel import in_background
    from ..sweeps import sweep

    # matplotlib (0.3 s) imports while the sweep runs: only the figures at the end need it
    plotting_ahead = in_background(importlib.import_module, "wfjax.plotting")
    case = resolve_case(args, "sweep", FLAGS)

    speeds = case.speeds()
    positions = case["run.impact_positions"]
    flats = case.flats()
    wheel, track, material, config = case.model()
    tracks = case.support_realisations(track)
    track = case.supports(track)
    rail_rough, wheel_rough = case.roughness(float(wheel.radius))
    contact = case["run.contact"]
    vehicle = case_vehicle(case, wheel)
    out = prepare_out(args.out)
    print(f"wfjax sweep: {len(flats)} flat(s) x {speeds.size} speeds x {positions} "
          f"positions, {contact} contact, R_R = {float(track.rail_head_radius):g} m, "
          f"{case['config.precision']}")
    t0 = time.perf_counter()
    result = sweep(flats, speeds, positions, contact=contact, wheel=wheel, track=track,
                   material=material, config=config, vehicle=vehicle, roughness=rail_rough,
                   wheel_roughness=wheel_rough, tracks=tracks)
    elapsed = time.perf_counter() - t0
    plotting_ahead.result()
    from ..plotting import percentile_band_figure, sweep_figure, sweep_wheels_figure

    check_finite("sweep", max_force=result.max_force, min_force=result.min_force)
    write_atomic(out / "sweep.csv", result.to_csv())
    extra = ", sweep_wheels.png" if vehicle is not None else ""
    if result.realisation_max_force is not None:
        write_atomic(out / "sweep_percentiles.csv", result.percentiles_to_csv())
        save_figure(percentile_band_figure(result, preload=float(wheel.preload)),
                    out / "sweep_band.png")
        extra += ", sweep_percentiles.csv, sweep_band.png"
    result.save_npz(out / "sweep.npz")
    summary = result.summary()
    summary["wall_time_s"] = elapsed
    summary["precision"] = case["config.precision"]
    write_summary(out / "sweep.json", summary, case,
                  {k: case.get(k) for k in ("flat.profile_csv", "roughness.rail_csv",
                                            "roughness.wheel_csv")})
    save_figure(sweep_figure(result, preload=float(wheel.preload)), out / "sweep.png")
    if vehicle is not None:
        save_figure(sweep_wheels_figure(result, preload=float(wheel.preload)),
                    out / "sweep_wheels.png")
    for label, s in summary["flats"].items():
        loss = s["first_loss_of_contact_kmh"]
        loss_text = f"from {loss:.0f} km/h" if loss is not None else "none"
        print(f"  {label}: peak max force {s['peak_max_force_kN']:.1f} kN at "
              f"{s['at_speed_kmh']:.0f} km/h; loss of contact {loss_text}; spread over "
              f"positions up to {s['max_spread_over_positions_percent']:.1f} %")
    for w, row in enumerate(summary.get("wheels", [])):
        print(f"  wheel {w} ({row['position_m']:g} m behind the leading): peak max force "
              f"{row['peak_max_force_kN']:.1f} kN, lowest min {row['lowest_min_force_kN']:.1f} "
              f"kN, axle-box acceleration up to {row['peak_axle_acc_m_s2']:.0f} m/s^2")
    for label, pct in summary.get("max_force_percentiles_kN", {}).items():
        j = int(np.argmax(pct["p95"]))
        print(f"  {label}: over {summary['realisations']} roughness realisations, max force "
              f"p50/p95/p99 {pct['p50'][j]:.1f} / {pct['p95'][j]:.1f} / {pct['p99'][j]:.1f} kN "
              f"at {speeds[j] * 3.6:.0f} km/h")
    print(f"  {elapsed:.1f} s; wrote {out}/sweep.csv, sweep.json, sweep.npz, sweep.png{extra}, "
          "case.toml")
    return 0

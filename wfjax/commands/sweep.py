"""``wfjax sweep``: max/min contact force against speed over impact positions (Fig. 7).

Flats: one kind (or ``--flat both``: a rounded and a new flat) at one depth or a list of
depths (``--depths-mm 0.25:2:0.25``), with one length for all, one length per depth
(``--lengths-mm``) or a length rule (``--length-factor 1.76``: l = 1.76 l0), or a measured
profile (``--profile-csv``). All flats go to one :func:`wfjax.sweep` call and into one CSV,
JSON, NPZ and PNG (one curve per flat); ``--format netcdf`` writes the labelled
``sweep.nc`` (:mod:`wfjax.labelled`) instead of, or with (``csv,netcdf``), the CSV.
"""

from __future__ import annotations

import time

import numpy as np

from .. import case as case_mod
from ..outsize import check_sweep
from ._common import (
    case_vehicle,
    check_finite,
    prepare_out,
    provenance,
    resolve_case,
    save_figure,
    write_atomic,
    write_summary,
)

HELP = "speed sweep of max/min contact force over impact positions (default: Fig. 7, 3D contact)"
INPUT_KEYS = ("flat.profile_csv", "flat.sections", "roughness.rail_csv",
              "roughness.wheel_csv")


def check_formats(formats: list[str]) -> None:
    """Refuse (:class:`wfjax.case.CaseError`, one line: exit 2, before any work) a format
    whose optional dependencies are missing: ``netcdf`` needs ``wfjax[io]``."""
    if "netcdf" in formats:
        from ..labelled import require

        try:
            require("--format netcdf")
        except ImportError as exc:
            raise case_mod.CaseError(str(exc)) from None


def run(args) -> int:
    import importlib

    from .._parallel import while_compiling
    from ..sweeps import sweep

    # matplotlib (0.4 s) imports while the sweep's program compiles: only the figures at the
    # end need it
    plotting_ahead = while_compiling(importlib.import_module, "wfjax.plotting")
    case = resolve_case(args, "sweep")
    check_formats(args.format)

    speeds = case.speeds()
    positions = case["run.impact_positions"]
    flats = case.flats()
    wheel, track, material, config = case.model()
    tracks = case.support_realisations(track)
    track = case.supports(track)
    rail_rough, wheel_rough = case.roughness(float(wheel.radius))
    from ..scenario.measured import case_wheel_roughness  # a flat.sections measurement's

    wheel_rough = case_wheel_roughness(case, wheel_rough)
    contact = case["run.contact"]
    vehicle = case_vehicle(case, wheel)
    check_sweep(case, len(flats), speeds.size, 1 if vehicle is None else vehicle.n_wheels,
                max(int(case.get("roughness.realisations", 1)), len(tracks or [None])))
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
    check_finite("sweep", max_force=result.max_force, min_force=result.min_force)
    summary = result.summary()
    summary["wall_time_s"] = elapsed
    summary["precision"] = case["config.precision"]
    written = _write(out, result, summary, case, args.format, float(wheel.preload))
    _report(summary, speeds)
    print(f"  {elapsed:.1f} s; wrote {out}/{', '.join(written)}")
    return 0


def _write(out, result, summary: dict, case, formats: list[str], preload: float) -> list[str]:
    """Write the sweep's files into ``out`` in ``formats``; returns their names.

    ``preload``: the static wheel load [N] the figures mark.
    """
    from ..plotting import percentile_band_figure, sweep_figure, sweep_wheels_figure

    written = []
    band = result.realisation_max_force is not None
    if "csv" in formats:
        write_atomic(out / "sweep.csv", result.to_csv())
        written.append("sweep.csv")
        if band:
            write_atomic(out / "sweep_percentiles.csv", result.percentiles_to_csv())
            written.append("sweep_percentiles.csv")
    inputs = {k: case.get(k) for k in INPUT_KEYS}
    if "netcdf" in formats:
        result.to_netcdf(out / "sweep.nc", case=case, provenance=provenance(case, inputs))
        written.append("sweep.nc")
    result.save_npz(out / "sweep.npz")
    write_summary(out / "sweep.json", summary, case, inputs)
    save_figure(sweep_figure(result, preload=preload), out / "sweep.png")
    written += ["sweep.npz", "sweep.json", "sweep.png"]
    if band:
        save_figure(percentile_band_figure(result, preload=preload), out / "sweep_band.png")
        written.append("sweep_band.png")
    if result.wheel_max_force is not None:
        save_figure(sweep_wheels_figure(result, preload=preload), out / "sweep_wheels.png")
        written.append("sweep_wheels.png")
    return written + ["case.toml"]


def _report(summary: dict, speeds) -> None:
    """Print the peak forces, loss-of-contact speeds, wheels and percentiles of ``summary``
    (``speeds`` [m/s])."""
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

"""``wfjax compare``: the four contact models for the flats of Figs. 9 and 10.

For every depth (default 0.5, 0.9 and 1.75 mm) a rounded and a new flat are swept over speed
and impact positions with each contact model (3D, 2D, Hertz with the wheel-centre trajectory,
Hertz with the profile deviation), on the comparison track with R_R = R_W = 0.45 m (paper,
Section 4: cylindrical profiles of the wheel radius for all models).

Rounded flat lengths: Section 4.3 repeats "a rounded wheel flat with depths 0.9 mm (Fig. 7)
and 0.5 mm and 1.75 mm (Fig. 8)", so the 0.9 mm flat is the Fig. 7 flat, l = 100 mm, and the
others are the Fig. 8 flats, l = 1.76 l0 with l0 = sqrt(8 R_W d). For 0.9 mm the two rules
nearly coincide (1.76 l0 = 100.2 mm): 1.76 is the ratio of the field-test flat's length to
its l0.
"""

from __future__ import annotations

import csv
import io
import sys
import time

import numpy as np

from ..contact import registry
from ..params import Flat, Track
from ._common import (
    prepare_out,
    resolve_case,
    save_figure,
    write_atomic,
    write_json,
)

HELP = "four contact models for rounded and new flats (Figs. 9 and 10: CSV, JSON, PNGs)"

COMPARISON_DEPTHS_MM = (0.5, 0.9, 1.75)
FIG7_LENGTH_MM = 100.0  # the field-test flat of Figs. 6 and 7
LENGTH_FACTOR = 1.76  # l = 1.76 l0 of Fig. 8


def comparison_flat(kind: str, depth_mm: float, wheel_radius: float = 0.45) -> Flat:
    """The flat of Figs. 9/10 of ``kind`` ("rounded" or "new") and depth ``depth_mm`` [mm].

    Rounded: l = 100 mm at d = 0.9 mm (Fig. 7), l = 1.76 l0 otherwise (Fig. 8).
    """
    depth = depth_mm * 1e-3
    if kind == "new":
        return Flat.new(depth, wheel_radius)
    if kind != "rounded":
        raise ValueError(f"flat kind must be 'rounded' or 'new', got {kind!r}")
    if abs(depth_mm - 0.9) < 1e-9:
        return Flat.rounded(depth, FIG7_LENGTH_MM * 1e-3, wheel_radius)
    return Flat.rounded_relative(depth, LENGTH_FACTOR, wheel_radius)


def comparison_flats(depths_mm=COMPARISON_DEPTHS_MM, wheel_radius: float = 0.45) -> list[Flat]:
    """[rounded d1, new d1, rounded d2, new d2, ...]: the panel order of Figs. 9 and 10, on a
    wheel of radius ``wheel_radius`` [m]."""
    depths = [float(d) for d in np.atleast_1d(depths_mm)]
    if not depths or not all(np.isfinite(d) and 0 < d <= 5 for d in depths):
        raise ValueError(f"--depths-mm must be depths in (0, 5] mm, got {depths_mm!r}")
    return [comparison_flat(k, d, wheel_radius) for d in depths for k in ("rounded", "new")]


def run_comparison(flats: list[Flat], speeds, positions: int = 8, models=None,
                   track: Track | None = None, progress: bool = True, wheel=None,
                   material=None, config=None) -> dict:
    """Sweep every contact model over the same flats, speeds [m/s] and impact positions.

    Args:
        flats: the flats (one panel each).
        speeds: [n_speeds] train speeds [m/s].
        positions: number of impact positions evenly covering one bay.
        models: contact models; ``"3d"`` must be among them (the reference). Default: every
            registered model (:func:`wfjax.contact.registry.names`).
        track: default :meth:`Track.comparison` (R_R = 0.45 m).
        wheel, material, config: model parameters (defaults as in :func:`wfjax.sweep`).
        progress: print per-model headers and the sweep's progress to stderr.

    Returns:
        model -> :class:`wfjax.SweepResult`, arrays [n_flats, n_speeds, positions].
    """
    from ..sweeps import sweep

    models = registry.names() if models is None else models
    if "3d" not in models:
        raise ValueError("the comparison needs the 3d model as reference")
    track = track or Track.comparison()
    results = {}
    for k, model in enumerate(models):
        if progress:
            print(f"[{k + 1}/{len(models)}] {model} contact", file=sys.stderr, flush=True)
        results[model] = sweep(flats, speeds, positions, contact=model, track=track,
                               wheel=wheel, material=material, config=config,
                               progress=progress)
    return results


def comparison_summary(results: dict, rail_head_radius_m: float = 0.45) -> dict:
    """Extremes over speeds of the relative deviation from 3D, per model and flat [%].

    Returns:
        JSON-ready dict: ``per_flat[model][flat]`` with the largest over- and
        underestimation (percent, and the speed in km/h where it occurs), and
        ``per_kind[model][kind]`` with the same taken over all depths of a kind.
    """
    from ..plotting_paper import relative_deviation

    ref = results["3d"]
    v = np.asarray(ref.speeds) * 3.6
    dev = relative_deviation(results)
    kinds = [label.split()[0] for label in ref.flats]
    per_flat, per_kind = {}, {}
    for model, d in dev.items():
        per_flat[model], per_kind[model] = {}, {}
        for i, label in enumerate(ref.flats):
            hi, lo = int(np.argmax(d[i])), int(np.argmin(d[i]))
            per_flat[model][label] = {
                "max_percent": 100 * float(d[i, hi]), "at_speed_kmh": float(v[hi]),
                "min_percent": 100 * float(d[i, lo]), "min_at_speed_kmh": float(v[lo]),
            }
        for kind in dict.fromkeys(kinds):
            rows = d[[i for i, k in enumerate(kinds) if k == kind]]
            per_kind[model][kind] = {"max_percent": 100 * float(rows.max()),
                                     "min_percent": 100 * float(rows.min())}
    return {
        "reference": "3d",
        "rail_head_radius_m": float(rail_head_radius_m),
        "speeds_kmh": [float(s) for s in v],
        "impact_positions": len(ref.impact_positions),
        "flats": list(ref.flats),
        "peak_max_force_kN": {m: {label: float(r.envelope()["max_force"][i].max()) / 1e3
                                  for i, label in enumerate(r.flats)}
                              for m, r in results.items()},
        "per_flat": per_flat,
        "per_kind": per_kind,
    }


def comparison_csv(results: dict) -> str:
    """One row per (flat, speed): max-over-positions force [kN] of each model and Delta_F [%]."""
    from ..plotting_paper import relative_deviation

    ref = results["3d"]
    dev = relative_deviation(results)
    env = {m: r.envelope() for m, r in results.items()}
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["flat", "speed_kmh"]
               + [f"max_force_{m}_kN" for m in results]
               + [f"loss_of_contact_{m}" for m in results]
               + [f"delta_F_{m}_percent" for m in dev])
    for i, label in enumerate(ref.flats):
        for j, s in enumerate(np.asarray(ref.speeds)):
            w.writerow([label, f"{s * 3.6:.6g}"]
                       + [f"{env[m]['max_force'][i, j] / 1e3:.6f}" for m in results]
                       + [int(env[m]["loss_of_contact"][i, j]) for m in results]
                       + [f"{100 * d[i, j]:.4f}" for d in dev.values()])
    return buf.getvalue()


def write_comparison(out, results: dict, rail_head_radius_m: float = 0.45,
                     extra: dict | None = None, prefix: str = "compare", case=None) -> dict:
    """Write the comparison's files into the directory ``out``.

    Files: ``<prefix>.csv`` (:func:`comparison_csv`), ``<prefix>.json`` (the summary plus
    ``extra``), one ``<prefix>_<model>.npz`` per model (the full sweeps), ``fig9_forces.png``
    and ``fig10_deviation.png``; with ``case`` (a :class:`wfjax.case.Case`) the JSON records
    it and its provenance, and ``case.toml`` is written too.

    Returns:
        The summary written to the JSON file (see :func:`comparison_summary`).
    """
    from ..plotting_paper import model_deviation_figure, model_forces_figure
    from ._common import write_summary

    summary = {**comparison_summary(results, rail_head_radius_m), **(extra or {})}
    if case is None:
        write_json(out / f"{prefix}.json", summary)
    else:
        write_summary(out / f"{prefix}.json", summary, case)
    write_atomic(out / f"{prefix}.csv", comparison_csv(results))
    for model, res in results.items():
        res.save_npz(out / f"{prefix}_{model}.npz")
    save_figure(model_forces_figure(results), out / "fig9_forces.png")
    save_figure(model_deviation_figure(results), out / "fig10_deviation.png")
    return summary


def print_summary(summary: dict, stream=None) -> None:
    """Human summary: per model and flat kind, the extremes of Delta_F over speeds [%]."""
    stream = stream or sys.stdout
    v = summary["speeds_kmh"]
    print(f"relative deviation from 3D, Delta_F = (F - F_3D)/F_3D of the maximum force "
          f"(max over {summary['impact_positions']} impact positions), "
          f"{v[0]:g}-{v[-1]:g} km/h:", file=stream)
    kinds = list(next(iter(summary["per_kind"].values())))
    print(f"  {'model':<18}" + "".join(f"{k:>24}" for k in kinds), file=stream)
    for model, per in summary["per_kind"].items():
        cells = "".join(f"{per[k]['min_percent']:+9.1f} % .. {per[k]['max_percent']:+6.1f} %"
                        for k in kinds)
        print(f"  {model:<18}{cells}", file=stream)
    for label, f in summary["peak_max_force_kN"]["3d"].items():
        print(f"  3D peak max force, {label}: {f:.1f} kN", file=stream)


def parse_models(text: str) -> tuple[str, ...]:
    """Contact models from ``"3d,2d,..."`` (3d must be included)."""
    models = tuple(m.strip() for m in text.split(",") if m.strip())
    names = registry.names()
    bad = [m for m in models if m not in names]
    if bad or "3d" not in models:
        raise ValueError(f"--models {text!r}: must be a comma-separated subset of "
                         f"{', '.join(names)} including 3d")
    return models


def run(args) -> int:
    case = resolve_case(args, "compare")
    speeds = case.speeds()
    positions = case["run.impact_positions"]
    depths = case["compare.depths_mm"]
    models = parse_models(",".join(case["compare.models"]))
    wheel, track, material, config = case.model()
    flats = comparison_flats(depths if isinstance(depths, list) else [depths],
                             float(wheel.radius))
    out = prepare_out(args.out)
    print(f"wfjax compare: {len(models)} models x {len(flats)} flats x {speeds.size} speeds x "
          f"{positions} positions, R_R = {float(track.rail_head_radius)} m")
    t0 = time.perf_counter()
    results = run_comparison(flats, speeds, positions, models, track, wheel=wheel,
                             material=material, config=config)
    elapsed = time.perf_counter() - t0
    summary = write_comparison(out, results, float(track.rail_head_radius),
                               extra={"wall_time_s": elapsed}, case=case)
    print_summary(summary)
    print(f"  {elapsed:.1f} s; wrote {out}/compare.csv, compare.json, compare_<model>.npz, "
          f"fig9_forces.png, fig10_deviation.png, case.toml")
    return 0

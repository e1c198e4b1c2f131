"""``wfjax figures``: regenerate every reproduced figure of the paper (Figs. 5, 7, 8, 9, 10).

* Fig. 5: profile deviation and wheel-centre trajectory of a new and a rounded 0.9 mm flat.
* Fig. 7: 0.9 mm rounded (l = 100 mm) and new flat, 3D contact, max and min force against
  speed over 10 impact positions (spread shown, loss of contact marked).
* Fig. 8: rounded flats of depth 0.25-2.00 mm, l = 1.76 l0, 3D contact, max over 8 impact
  positions with loss-of-contact markers.
* Figs. 9 and 10: the contact-model comparison of ``wfjax compare``.

All on the paper's Section 4 track, R_R = R_W = 0.45 m (``Track.comparison()``): the paper
uses the 0.30 m rail head only for its field comparison (Section 4.1, Fig. 6), which is not
reproduced here because the measured data are not available.

``--config case.toml`` replaces the paper's wheel, track, material and numerical settings by
the case file's (``[wheel]``, ``[track]``, ``[material]``, ``[config]``; default: the paper's,
``Track.comparison()``); the flats and speeds stay the paper's.

``--fast`` shrinks every sweep (3 speeds, 2 positions, fewer depths) for smoke tests.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from ..case import parse_number_list
from ..params import Flat
from ._common import (
    prepare_out,
    resolve_case,
    save_figure,
    write_atomic,
    write_summary,
)
from .compare import (
    COMPARISON_DEPTHS_MM,
    comparison_flat,
    comparison_flats,
    run_comparison,
    write_comparison,
)

HELP = "regenerate the paper's Figs. 5, 7, 8, 9 and 10 (PNG, CSV, NPZ, JSON)"

FIGURES = ("5", "7", "8", "9")  # "9" makes Figs. 9 and 10 (one comparison run)
FIG8_DEPTHS_MM = tuple(0.25 * k for k in range(1, 9))  # 0.25 ... 2.00 mm
FAST = {"speeds_kmh": "40,100,160", "positions": 2, "fig8_depths_mm": (0.5, 2.0),
        "compare_depths_mm": (0.9,)}


def fig7_flats(wheel_radius: float = 0.45) -> list[Flat]:
    """The flats of Fig. 7: rounded 0.9 mm with l = 100 mm, and new 0.9 mm, on a wheel of
    radius ``wheel_radius`` [m]."""
    return [comparison_flat("rounded", 0.9, wheel_radius),
            comparison_flat("new", 0.9, wheel_radius)]


def fig8_flats(depths_mm=FIG8_DEPTHS_MM, wheel_radius: float = 0.45) -> list[Flat]:
    """The rounded flats of Fig. 8: depth d [mm] each, l = 1.76 l0, on a wheel of radius
    ``wheel_radius`` [m]."""
    return [Flat.rounded_relative(d * 1e-3, 1.76, wheel_radius) for d in depths_mm]


def _write_sweep(out, name: str, result, elapsed: float, case) -> dict:
    write_atomic(out / f"{name}.csv", result.to_csv())
    result.save_npz(out / f"{name}.npz")
    summary = {**result.summary(), "wall_time_s": elapsed}
    write_summary(out / f"{name}.json", summary, case)
    return summary


def parse_figures(text: str) -> tuple[str, ...]:
    """Figure numbers from ``"5,7,8,9"`` ("9" and "10" both mean the comparison run)."""
    wanted = [p.strip() for p in text.split(",") if p.strip()]
    bad = [p for p in wanted if p not in (*FIGURES, "10")]
    if bad or not wanted:
        raise ValueError(f"--only must be a comma-separated subset of 5,7,8,9,10, got {text!r}")
    return tuple(f for f in FIGURES if f in wanted or (f == "9" and "10" in wanted))


def run(args) -> int:
    from ..plotting import default_fig5_flats, flat_inputs_figure, sweep_figure
    from ..plotting_paper import depth_family_figure
    from ..sweeps import sweep

    wanted = parse_figures(args.only)
    case = resolve_case(args, "figures")
    wheel, track, material, config = case.model()
    model = dict(wheel=wheel, track=track, material=material, config=config)
    rr = f"R_R = {float(track.rail_head_radius):g} m"
    speeds = np.asarray(parse_number_list(args.speeds_kmh or (
        FAST["speeds_kmh"] if args.fast else "20:300:10"))) / 3.6
    pos7, pos8 = (FAST["positions"],) * 2 if args.fast else (10, 8)
    depths8 = FAST["fig8_depths_mm"] if args.fast else FIG8_DEPTHS_MM
    depths9 = FAST["compare_depths_mm"] if args.fast else COMPARISON_DEPTHS_MM
    out = prepare_out(args.out)
    print(f"wfjax figures: Figs. {', '.join(wanted)}{' (fast)' if args.fast else ''}, "
          f"{speeds.size} speeds {speeds[0] * 3.6:g}-{speeds[-1] * 3.6:g} km/h -> {out}")
    report: dict = {"fast": bool(args.fast), "speeds_kmh": [float(s * 3.6) for s in speeds]}
    written = []
    t_all = time.perf_counter()

    if "5" in wanted:
        save_figure(flat_inputs_figure(default_fig5_flats()), out / "fig5_inputs.png")
        written.append("fig5_inputs.png")

    if "7" in wanted:
        print(f"Fig. 7: 0.9 mm rounded and new flats, 3D, {rr}", file=sys.stderr)
        t0 = time.perf_counter()
        res = sweep(fig7_flats(float(wheel.radius)), speeds, pos7, contact="3d", **model)
        report["fig7"] = _write_sweep(out, "fig7", res, time.perf_counter() - t0, case)
        save_figure(sweep_figure(res, title=f"Fig. 7: 0.9 mm flats, 3D contact, max/min over "
                                            f"{pos7} impact positions; filled: loss of contact",
                                 preload=float(wheel.preload)),
                    out / "fig7_speed_sweep.png")
        written += ["fig7.csv", "fig7.json", "fig7.npz", "fig7_speed_sweep.png"]

    if "8" in wanted:
        print(f"Fig. 8: {len(depths8)} rounded flats (l = 1.76 l0), 3D, {rr}", file=sys.stderr)
        t0 = time.perf_counter()
        res = sweep(fig8_flats(depths8, float(wheel.radius)), speeds, pos8, contact="3d",
                    **model)
        report["fig8"] = _write_sweep(out, "fig8", res, time.perf_counter() - t0, case)
        save_figure(depth_family_figure(res, depths_mm=np.asarray(depths8)),
                    out / "fig8_depths.png")
        written += ["fig8.csv", "fig8.json", "fig8.npz", "fig8_depths.png"]

    if "9" in wanted:
        print(f"Figs. 9/10: four contact models, {rr}", file=sys.stderr)
        t0 = time.perf_counter()
        results = run_comparison(comparison_flats(depths9, float(wheel.radius)), speeds, pos8,
                                 **model)
        summary = write_comparison(out, results, float(track.rail_head_radius),
                                   extra={"wall_time_s": time.perf_counter() - t0}, case=case)
        report["fig9_10"] = summary["per_kind"]
        written += ["compare.csv", "compare.json", "compare_<model>.npz", "fig9_forces.png",
                    "fig10_deviation.png"]

    report["wall_time_s"] = time.perf_counter() - t_all
    write_summary(out / "figures.json", report, case)
    for key in ("fig7", "fig8"):
        for label, s in report.get(key, {}).get("flats", {}).items():
            loss = s["first_loss_of_contact_kmh"]
            print(f"  Fig. {key[-1]} {label}: peak {s['peak_max_force_kN']:.1f} kN at "
                  f"{s['at_speed_kmh']:.0f} km/h, loss of contact "
                  f"{f'from {loss:.0f} km/h' if loss is not None else 'none'}")
    for model, per in report.get("fig9_10", {}).items():
        cells = ", ".join(f"{k} {v['min_percent']:+.1f}..{v['max_percent']:+.1f} %"
                          for k, v in per.items())
        print(f"  Figs. 9/10 {model} vs 3D: {cells}")
    print(f"  {report['wall_time_s']:.1f} s; wrote {out}/"
          + ", ".join(written + ["figures.json", "case.toml"]))
    return 0

"""The new flat's min force near loss of contact against the 3D law's evaluation, the contact
element and the time step (issue 33, docs/convergence.md "Min force").

New 0.9 mm flat at 40 km/h (just below loss of contact), 3D contact, modes to 20 kHz,
float64. Two sections:

* ``elements``: exact tables, R_R = 0.45 m, 5 impact positions, 50 bays: the min and max
  force at contact elements of 1 mm (the paper's and the reference's) and 0.5 mm, each at the
  reference's step (6.25 us / 0.25 mm) and the default's (40 us / 1 mm).
* ``direct``: the exact table against a Kalker solve at every Newton iterate
  (``SimConfig(contact_mode_3d="direct")``, the independent reference of the tabulated law),
  1 mm elements, impact positions 0 and 0.26 m, the default track (24 bays, R_R = 0.3 m), at
  both steps. The direct runs take minutes (about 10 at 6.25 us).

Run: ``python benchmarks/min_force_element.py [--sections elements,direct]``; writes
``benchmarks/results/min_force_element.json`` and prints Markdown tables.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import time

import numpy as np

import wfjax as wf

SPEED_KMH = 40.0
STEPS = {"6.25 us / 0.25 mm": (6.25e-6, 0.25e-3), "40 us / 1 mm": (40e-6, 1e-3)}
ELEMENTS = (1e-3, 0.5e-3)  # m
OUT = pathlib.Path(__file__).parent / "results" / "min_force_element.json"


def run(element: float, step: tuple[float, float], mode: str = "table", positions=5,
        track=None) -> dict:
    """Min and max force [N] [positions] of one setting, and its time [s]."""
    cfg = wf.SimConfig(max_time_step=step[0], max_travel_step=step[1],
                       track_max_frequency=20e3, contact_element=element,
                       precision="float64", allow_inaccurate=True, contact_mode_3d=mode)
    t0 = time.perf_counter()
    r = wf.sweep(wf.Flat.new(0.9e-3), np.array([SPEED_KMH]) / 3.6, positions, contact="3d",
                 track=track, config=cfg, progress=False)
    return {"min_force": np.asarray(r.min_force)[0, 0].tolist(),
            "max_force": np.asarray(r.max_force)[0, 0].tolist(),
            "seconds": time.perf_counter() - t0}


def markdown(rows: dict, reference: str, same) -> str:
    """A Markdown table of ``rows``: min and max forces, the min force's largest distance
    from ``same(label)``'s and from ``reference``'s [%P of the static load]."""
    load = float(wf.Wheel().preload)
    lines = ["| setting | min force kN | max force kN | min vs the same law at 6.25 us, %P | "
             f"min vs {reference}, %P |", "|---|---|---|---|---|"]
    for label, r in rows.items():
        d, d1 = (100 * np.max(np.abs(np.subtract(r["min_force"], rows[x]["min_force"]))) / load
                 for x in (same(label), reference))
        lines.append(f"| {label} | {', '.join(f'{x / 1e3:.2f}' for x in r['min_force'])} | "
                     f"{', '.join(f'{x / 1e3:.1f}' for x in r['max_force'])} | {d:.2f} | "
                     f"{d1:.2f} |")
    return "\n".join(lines)


def elements() -> dict:
    rows = {f"{e * 1e3:g} mm, {label}": run(e, step, track=wf.Track.comparison(n_bays=50))
            for e in ELEMENTS for label, step in STEPS.items()}
    print(markdown(rows, "1 mm, 6.25 us / 0.25 mm",
                   lambda label: label.split(",")[0] + ", 6.25 us / 0.25 mm"), flush=True)
    return rows


def direct() -> dict:
    rows = {f"{mode}, {label}": run(1e-3, step, mode, np.array([0.0, 0.26]))
            for mode in ("direct", "table") for label, step in STEPS.items()}
    print(markdown(rows, "direct, 6.25 us / 0.25 mm",
                   lambda label: label.split(",")[0] + ", 6.25 us / 0.25 mm"), flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sections", default="elements,direct")
    args = ap.parse_args()
    done = json.loads(OUT.read_text()) if OUT.exists() else {}
    done = done if "sections" in done else {"sections": {}}
    for name in args.sections.split(","):
        done["sections"][name] = {"elements": elements, "direct": direct}[name]()
        done |= {"speed_kmh": SPEED_KMH, "static_load_N": float(wf.Wheel().preload)}
        OUT.write_text(json.dumps(done, indent=1))


if __name__ == "__main__":
    main()

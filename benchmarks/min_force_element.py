"""The new flat's min force near loss of contact against the 3D contact element and the time
step (issue 33, docs/convergence.md "Min force").

New 0.9 mm flat at 40 km/h (just below loss of contact), 3D contact (exact tables), R_R =
0.45 m, 5 impact positions, 50 bays, modes to 20 kHz, float64: the min and max force at
contact elements of 1 mm (the paper's and the reference's) and 0.5 mm, each at the
reference's step (6.25 us / 0.25 mm) and the default's (40 us / 1 mm).

Run: ``python benchmarks/min_force_element.py``; writes
``benchmarks/results/min_force_element.json`` and prints a Markdown table.
"""

from __future__ import annotations

import json
import pathlib
import time

import numpy as np

import wfjax as wf

SPEED_KMH = 40.0
STEPS = {"6.25 us / 0.25 mm": (6.25e-6, 0.25e-3), "40 us / 1 mm": (40e-6, 1e-3)}
ELEMENTS = (1e-3, 0.5e-3)  # m


def run(element: float, step: tuple[float, float]) -> dict:
    """Min and max force [N] [5 positions] of one setting, and its time [s]."""
    cfg = wf.SimConfig(max_time_step=step[0], max_travel_step=step[1],
                       track_max_frequency=20e3, contact_element=element,
                       precision="float64", allow_inaccurate=True)
    t0 = time.perf_counter()
    r = wf.sweep(wf.Flat.new(0.9e-3), np.array([SPEED_KMH]) / 3.6, 5, contact="3d",
                 track=wf.Track.comparison(n_bays=50), config=cfg, progress=False)
    return {"min_force": np.asarray(r.min_force)[0, 0].tolist(),
            "max_force": np.asarray(r.max_force)[0, 0].tolist(),
            "seconds": time.perf_counter() - t0}


def main() -> None:
    rows = {f"{e * 1e3:g} mm, {label}": run(e, step)
            for e in ELEMENTS for label, step in STEPS.items()}
    load = float(wf.Wheel().preload)
    first = rows["1 mm, 6.25 us / 0.25 mm"]["min_force"]  # the accuracy table's reference
    print("| element, step | min force kN (5 positions) | max force kN | min vs the same "
          "element at 6.25 us, %P | min vs 1 mm at 6.25 us, %P |\n|---|---|---|---|---|")
    for label, r in rows.items():
        ref = rows[label.split(",")[0] + ", 6.25 us / 0.25 mm"]["min_force"]
        d, d1 = (100 * np.max(np.abs(np.subtract(r["min_force"], x))) / load
                 for x in (ref, first))
        print(f"| {label} | {', '.join(f'{x / 1e3:.2f}' for x in r['min_force'])} | "
              f"{', '.join(f'{x / 1e3:.1f}' for x in r['max_force'])} | {d:.2f} | "
              f"{d1:.2f} |")
    out = pathlib.Path(__file__).parent / "results" / "min_force_element.json"
    out.write_text(json.dumps({"speed_kmh": SPEED_KMH, "static_load_N": load,
                               "rows": rows}, indent=1))


if __name__ == "__main__":
    main()

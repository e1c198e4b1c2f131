"""How far the identification's own track model reads from the converged reference (issue 31,
docs/identify.md "Method", Track).

The identification and its validation studies run on ``wfjax.identify.forward.TRACK`` (70 bays
of 8 elements, the package's defaults before 2026-12-03) at a detector reading's settings
(15 kHz, 25 us, float64), not on the accuracy table's reference (26 elements per bay, 20 kHz,
6.25 us, 0.25 mm, docs/convergence.md). Its readings therefore carry a model error, which the
identification's noise model covers with its ``model`` term (2 %). This measures it on the
cases the identification tabulates: one wheel over the 5-bay detector of the studies, new
40 and 80 mm and rounded 80 mm (l / l0 = 1.8) flats, struck at 0.15, 0.30 and 0.45 m into bay
0, at 60, 100 and 140 km/h, no roughness, one strike (the response table's runs). Columns:
the identification's model (``id``), the same at 26 elements per bay (``26 el``) and the
reference (``ref``); the relative differences of the highest bay reading and of the peak
contact force against the reference.

Run: ``python benchmarks/identify_track_mesh.py`` (about 5 minutes on 2 cores); writes
``benchmarks/results/identify_track_mesh.json`` and prints a Markdown table.
"""

from __future__ import annotations

import json
import pathlib
import time

import numpy as np

import wfjax as wf
from wfjax.identify import forward as F

FLATS = (("new", 40e-3, 0.0), ("new", 80e-3, 0.0), ("rounded", 80e-3, 1.8))
IMPACTS_M = (0.15, 0.30, 0.45)
SPEEDS_KMH = (60.0, 100.0, 140.0)
MODELS = {  # label -> (track, config)
    "id": (F.TRACK, None),
    "26 el": (wf.Track(n_bays=70, elements_per_bay=26), None),
    "ref": (wf.Track(n_bays=70, elements_per_bay=26),
            wf.SimConfig(track_max_frequency=20e3, max_time_step=6.25e-6,
                         max_travel_step=0.25e-3, precision="float64")),
}


def readings() -> list[dict]:
    """Every case's highest bay reading and peak contact force [N] per model."""
    wheel, detector = wf.Wheel(), wf.Detector(5, -1)
    radius = float(wheel.radius)
    rows = []
    for v in SPEEDS_KMH:
        for kind, length, factor in FLATS:
            for impact in IMPACTS_M:
                row = {"speed_kmh": v, "flat": f"{kind} {length * 1e3:.0f} mm", "impact_m": impact}
                for label, (track, config) in MODELS.items():
                    peaks, force = F.coupled_readings(
                        [F.flat_of(kind, length, factor, radius)], [impact], [0.0], v / 3.6,
                        detector, track=track, wheel=wheel, config=config)
                    row[label] = {"reading_N": float(peaks[0].max()), "force_N": float(force[0])}
                rows.append(row)
                print(row, flush=True)
    return rows


def summary(rows: list[dict]) -> dict:
    """Median and largest |relative difference| [%] against the reference, and the mean signed
    one, per model and quantity."""
    out = {}
    for label in MODELS:
        if label == "ref":
            continue
        for q in ("reading_N", "force_N"):
            d = 100 * np.array([r[label][q] / r["ref"][q] - 1 for r in rows])
            out[f"{label} {q}"] = {"median_abs_pct": float(np.median(np.abs(d))),
                                   "max_abs_pct": float(np.max(np.abs(d))),
                                   "mean_pct": float(np.mean(d))}
    return out


def main() -> None:
    t0 = time.perf_counter()
    rows = readings()
    result = {"date": time.strftime("%Y-%m-%d"), "wall_s": time.perf_counter() - t0,
              "summary": summary(rows), "rows": rows}
    path = pathlib.Path(__file__).parent / "results" / "identify_track_mesh.json"
    path.write_text(json.dumps(result, indent=1))
    print("\n| model | quantity | median abs. diff. | largest | mean signed |")
    print("|---|---|---|---|---|")
    for key, s in result["summary"].items():
        label, q = key.rsplit(" ", 1)
        print(f"| {label} | {q.split('_')[0]} | {s['median_abs_pct']:.2f} % | "
              f"{s['max_abs_pct']:.2f} % | {s['mean_pct']:+.2f} % |")


if __name__ == "__main__":
    main()

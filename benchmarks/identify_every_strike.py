"""The identification's every-strike rule against runs with every strike (issue 31,
docs/identify.md "Every strike").

A flat strikes every 2 pi R. The identification reads a detector bay from its one-strike
response table at the flat's last strike at or before that bay
(:func:`wfjax.identify.prediction.predict`). Here, for one wheel on the identification's
track (no roughness, Hertz-trajectory), ``predict`` runs on a table of single-strike runs of
the table's layout (the impact bay and the 4 after it, 20 positions per bay; a round wheel's
runs as its shortest flat) and is compared bay by bay with coupled runs in which the flat
strikes every revolution
(``Vehicle.repeat_flats``), over a 5-bay detector from the impact coordinate's bay 0, at
every ``--every``-th table position of one circumference. The one-strike rule (bays before
the strike and more than 4 after it read a round wheel) is shown beside it.

Run: ``python benchmarks/identify_every_strike.py [--every 3]`` (about 2 minutes on 2 cores);
writes ``benchmarks/results/identify_every_strike.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import jax
import numpy as np

from wfjax.identify import forward as fwd
from wfjax.identify import prediction
from wfjax.params import Wheel
from wfjax.scenario.sensors import Detector

jax.config.update("jax_enable_x64", True)

CASES = (("new", 0.0, 0.08), ("rounded", 1.8, 0.08), ("new", 0.0, 0.03))  # kind, l/l0, l [m]
SPEEDS_KMH = (60.0, 140.0)
OUT = Path(__file__).resolve().parent / "results" / "identify_every_strike.json"


def _one_strike(table: fwd.ResponseTable, phases: np.ndarray) -> np.ndarray:
    """[P, 5] readings [N] of detector bays 0..4 with the strike at ``phases`` [P] m only:
    the table's flat row in the strike's bay and the 4 after it, its round row elsewhere."""
    ls, n_j = table.sleeper_spacing, table.offsets.size
    idx = np.round(phases / (ls / n_j)).astype(int)
    rel = np.arange(5)[None, :] - np.floor_divide(idx, n_j)[:, None]  # [P, 5]
    near = (rel >= 0) & (rel < 5)
    t = table.readings[0, :, :, 0]  # [2, J, 5]: round, flat
    j = np.mod(idx, n_j)[:, None]
    return np.where(near, t[1, j, np.clip(rel, 0, 4)], t[0, j, np.arange(5)[None, :]])


def compare(kind: str, factor: float, length: float, kmh: float, every: int = 3) -> dict:
    """Largest and median relative differences [%] from every-strike runs of the
    identification's prediction (:func:`wfjax.identify.prediction.predict` on a table of this
    flat's single-strike runs) and of the one-strike rule, one flat (``kind``, l / l0
    ``factor``, ``length`` [m]) at ``kmh`` [km/h]."""
    radius = float(Wheel().radius)
    circumference, ls, n_j = 2 * math.pi * radius, 0.65, fwd.N_OFFSETS
    step, v, det = ls / n_j, kmh / 3.6, Detector(5, 0)
    flats = [fwd.round_wheel(radius), fwd.flat_of(kind, length, factor, radius)]
    single = [fwd.coupled_batch([([f], [u]) for u in np.arange(n_j) * step], [0.0], v, det,
                                repeat_flats=False)[0][:, 0] for f in flats]  # [J, 5] each
    reads = np.stack(single)[None, :, :, None, :]  # [S=1, L=2 (round, flat), J, R=1, 5]
    table = fwd.ResponseTable(v, ls, radius, (("new", 0.0),), np.array([0.0, length]),
                              np.arange(n_j) * step, reads, reads.max(axis=-1))
    phases = np.arange(0, int(round(circumference / step)), every) * step
    runs = fwd.coupled_batch([([flats[1]], [x]) for x in phases], [0.0], v, det)[0][:, 0]
    rules = {"every strike": prediction.predict(table, np.arange(5), [length],
                                                phases)[0, 0, :, 0],
             "one strike": _one_strike(table, phases)}
    out = {}
    for label, mu in rules.items():
        e = np.abs(mu / runs - 1)
        out[label] = {"max_pct": round(100 * float(e.max()), 3),
                      "median_pct": round(100 * float(np.median(e)), 4)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--every", type=int, default=3, help="every n-th table position")
    args = ap.parse_args()
    rows = {}
    for kmh in SPEEDS_KMH:
        for kind, factor, length in CASES:
            t0 = time.perf_counter()
            label = f"{kind} {length * 1e3:.0f} mm" + (f" (l/l0 {factor})" if factor else "")
            rows[f"{label}, {kmh:.0f} km/h"] = compare(kind, factor, length, kmh, args.every)
            print(label, kmh, rows[f"{label}, {kmh:.0f} km/h"],
                  f"{time.perf_counter() - t0:.0f} s", flush=True)
    OUT.write_text(json.dumps({"date": time.strftime("%Y-%m-%d"), "every": args.every,
                               "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()

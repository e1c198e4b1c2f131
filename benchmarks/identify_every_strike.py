"""The identification's every-strike rule against runs with every strike (issue 31,
docs/identify.md "Every strike").

A flat strikes every 2 pi R. The identification reads a detector bay from its one-strike
response table at the flat's last strike at or before that bay
(:func:`wfjax.identify.prediction.predict`). Here, for one wheel on the identification's
track (no roughness, Hertz-trajectory), the rule is evaluated from single-strike runs of the
table's layout (the impact bay and the 4 after it, 20 positions per bay) and compared bay by
bay with coupled runs in which the flat strikes every revolution
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
from wfjax.params import Wheel
from wfjax.scenario.sensors import Detector

jax.config.update("jax_enable_x64", True)

CASES = (("new", 0.0, 0.08), ("rounded", 1.8, 0.08), ("new", 0.0, 0.03))  # kind, l/l0, l [m]
SPEEDS_KMH = (60.0, 140.0)
OUT = Path(__file__).resolve().parent / "results" / "identify_every_strike.json"


def _rule(table: np.ndarray, smooth: float, phases: np.ndarray, step: float, n_j: int,
          circumference: float, every_strike: bool) -> np.ndarray:
    """[P, 5] readings [N] of detector bays 0..4 by the rule from single-strike runs
    ``table`` [n_j, 5] (bay offsets 0..4 after the impact bay) and a round wheel's reading
    ``smooth``: each bay at the flat's last strike at or before it (``every_strike``), or at
    the strike at ``phases`` only."""
    k = np.arange(-2, 3) if every_strike else np.zeros(1, int)
    out = np.full((phases.size, 5), smooth)
    for p, x in enumerate(phases):
        idx = np.round((x + k * circumference) / step).astype(int)
        q, j = np.floor_divide(idx, n_j), np.mod(idx, n_j)
        for b in range(5):
            ok = q <= b
            if ok.any():
                i = int(np.argmax(np.where(ok, q, np.iinfo(int).min)))
                if b - q[i] < 5:
                    out[p, b] = table[j[i], b - q[i]]
    return out


def compare(kind: str, factor: float, length: float, kmh: float, every: int = 3) -> dict:
    """Largest and median relative differences of the every-strike and one-strike rules from
    every-strike runs, one flat (``kind``, l / l0 ``factor``, ``length`` [m]) at ``kmh``."""
    radius = float(Wheel().radius)
    circumference, ls, n_j = 2 * math.pi * radius, 0.65, fwd.N_OFFSETS
    step, v, det = ls / n_j, kmh / 3.6, Detector(5, 0)
    flat = fwd.flat_of(kind, length, factor, radius)
    single, _ = fwd.coupled_batch([([flat], [u]) for u in np.arange(n_j) * step], [0.0], v,
                                  det, repeat_flats=False)
    round_wheel = fwd.flat_of("new", 4e-3, 0.0, radius)
    smooth, _ = fwd.coupled_batch([([round_wheel], [0.3])], [0.0], v, det, repeat_flats=False)
    phases = np.arange(0, int(round(circumference / step)), every) * step
    runs, _ = fwd.coupled_batch([([flat], [x]) for x in phases], [0.0], v, det)
    runs = runs[:, 0]
    out = {}
    for label, every_strike in (("every strike", True), ("one strike", False)):
        e = np.abs(_rule(single[:, 0], float(smooth[0, 0, 2]), phases, step, n_j,
                         circumference, every_strike) / runs - 1)
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

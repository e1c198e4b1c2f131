"""How long a track a point receptance needs (``guards.RECEPTANCE_BAYS``, ``wfjax receptance``).

Run: ``python benchmarks/receptance_length.py`` (about 5 minutes). The direct FE point
receptances of the default track (:func:`wfjax.track.receptance`, no modes) above a sleeper
and at midspan, 1500 log-spaced frequencies 20 Hz - 2 kHz, on 140-400 bays against an
800-bay track: the largest relative difference |H - H_800| / |H_800| outside the
pinned-pinned band (900-990 Hz) and inside it. Writes
``benchmarks/results/receptance_length.json`` and prints a Markdown table.

The clamped ends' standing waves shape the lightly damped pinned-pinned peak (943 Hz), where
the rail's waves barely decay over the sleepers: there the finite track's receptance does not
converge pointwise with its length (800 against 1000 bays: 10 % at 943 Hz), and a coarse
frequency grid steps over the peak and understates the difference.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import time

import numpy as np

import wfjax as wf
from wfjax import track as T

BAYS = (140, 200, 400)
LIMIT = 800
PEAK = (900.0, 990.0)  # Hz: the pinned-pinned band
BANDS = {"outside 900-990 Hz": lambda f: (f < PEAK[0]) | (f > PEAK[1]),
         "900-990 Hz": lambda f: (f >= PEAK[0]) & (f <= PEAK[1])}


def receptances(n_bays: int, f: np.ndarray) -> dict:
    """Point receptances [m/N] above a sleeper and at midspan on ``n_bays`` bays."""
    track = dataclasses.replace(wf.Track(ends="absorbing"), n_bays=n_bays)
    return {"sleeper": T.receptance(track, f, 0.0),
            "midspan": T.receptance(track, f, float(track.sleeper_spacing) / 2)}


def main() -> None:
    f = np.geomspace(20.0, 2000.0, 1500)
    t0 = time.perf_counter()
    limit = receptances(LIMIT, f)
    rows = []
    for n in BAYS:
        h = receptances(n, f)
        row = {"n_bays": n}
        for where in ("sleeper", "midspan"):
            e = np.abs(h[where] - limit[where]) / np.abs(limit[where])
            for band, within in BANDS.items():
                sel = within(f)
                row[f"{where} {band} %"] = 100 * float(e[sel].max())
                row[f"{where} {band} at Hz"] = float(f[sel][np.argmax(e[sel])])
        rows.append(row)
    out = pathlib.Path(__file__).parent / "results" / "receptance_length.json"
    out.write_text(json.dumps({"limit_bays": LIMIT, "rows": rows,
                               "seconds": time.perf_counter() - t0}, indent=1))
    cols = [k for k in rows[0] if k.endswith("%")]
    print("| bays | " + " | ".join(cols) + " |")
    print("| --- |" + " --- |" * len(cols))
    for row in rows:
        print(f"| {row['n_bays']} | " + " | ".join(f"{row[c]:.2f}" for c in cols) + " |")


if __name__ == "__main__":
    main()

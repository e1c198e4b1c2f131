"""How long must the modelled track be? The detector reading and the receptances against the
track's length, with the mesh and modes held fixed (issue 33: "a track long enough that more
bays change nothing").

Two measurements, both against the longest track of the run:

- ``reading``: the sharp set of ``accuracy_table.py`` (new flat 0.9 mm at 120, 160 and
  200 km/h, Hertz-trajectory, 10 impact positions, the 3-bay detector and the seat forces of
  the impact bay's sleepers) at the default mesh, modes and step (8 el./bay, 10 kHz, 25 us /
  1 mm) on 36, 50, 70, 100 and 140 bays: the largest relative change of the max force, seat
  force and detector reading (largest bay) against 140 bays;
- ``receptance``: the direct FE transfer receptance (no modes: a sparse solve per frequency,
  :func:`wfjax.model.track.receptance`) from 0.3 m to 1.0 m and 3.0 m, 20 Hz - 2 kHz
  (60 log-spaced points), on 20-200 bays against 300 bays: the largest relative difference
  over frequency and where it is.

Run: ``python benchmarks/track_length.py [--skip-reading]``; writes
``benchmarks/results/track_length.json`` and prints both tables.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

import numpy as np

import wfjax as wf
from wfjax.model import track as track_mod

sys.path.insert(0, str(pathlib.Path(__file__).parent))
import accuracy_table as at  # noqa: E402  (the sharp set and its settings)

OUT = pathlib.Path(__file__).parent / "results" / "track_length.json"
FREQS = np.geomspace(20.0, 2000.0, 60)
READING_BAYS = (36, 50, 70, 100, 140)
RECEPTANCE_BAYS = (20, 30, 50, 70, 100, 140, 200, 300)


def reading_runs() -> dict:
    """The sharp set at the default mesh, modes and step on each of ``READING_BAYS``."""
    return {nb: at.run_sharp({**at.REF, **at.OLD, "n_bays": nb}, quick=False)
            for nb in READING_BAYS}


def receptances() -> dict:
    """[n_f, 2] direct transfer receptances [m/N] 0.3 -> (1.0, 3.0) m per track length."""
    out = {}
    for nb in RECEPTANCE_BAYS:
        h = track_mod.receptance(wf.Track.comparison(n_bays=nb), FREQS, 0.3,
                                 np.array([1.0, 3.0]))
        out[nb] = h
    return out


def _rel(a, b) -> float:
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b) / np.abs(b)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skip-reading", action="store_true", help="receptances only (seconds)")
    args = ap.parse_args()
    result = {}
    rec = receptances()
    ref = rec[RECEPTANCE_BAYS[-1]]
    print("| bays | receptance 0.3->1.0 m % | 0.3->3.0 m % | at [Hz] |\n| --- | --- | --- | --- |")
    for nb, h in rec.items():
        err = np.abs(h - ref) / np.abs(ref)
        result[f"receptance {nb}"] = {"max_rel_%": (100 * err.max(axis=0)).tolist(),
                                      "at_hz": float(FREQS[np.argmax(err[:, 0])])}
        print(f"| {nb} | {100 * err[:, 0].max():.2f} | {100 * err[:, 1].max():.2f} | "
              f"{FREQS[np.argmax(err[:, 0])]:.0f} |")
    if not args.skip_reading:
        runs = reading_runs()
        last = runs[READING_BAYS[-1]]
        print("\n| bays | max force % | seat force % | detector reading % |\n"
              "| --- | --- | --- | --- |")
        for nb, r in runs.items():
            e = {k: 100 * _rel(r[k], last[k]) for k in ("max_force", "seat_force", "reading")}
            result[f"sharp {nb}"] = {"errors_%": e, "run": r}
            print(f"| {nb} | {e['max_force']:.2f} | {e['seat_force']:.2f} | "
                  f"{e['reading']:.2f} |")
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(result))


if __name__ == "__main__":
    main()

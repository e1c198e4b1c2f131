"""The neighbour corrections' track, old against new (issue 31, docs/identify.md "Speed"):
study wagons of the Hertz study's kept passages identified alternately with the corrections
on the 70-bay ``forward.TRACK`` (before 2026-12-05, night) and on ``forward.CORRECTION_TRACK``
(the same track at its least length; the guards lengthen it to 36 bays), one process,
nothing else changed. Per wagon and way (the order alternates): one identification that
compiles what it needs (its seconds kept as ``first_seconds``), then ``--rounds`` timed
ones with the programs compiled, as in a study or a wayside service; and the largest
difference of any wheel's length median [mm], P(flag) and misfit.

    python benchmarks/identify_correction_track.py --passages DIR --wagons 1,19,22,29,55

Writes ``benchmarks/results/identify_correction_track.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from identify_study import kept_passages  # benchmarks/, the script's folder

ROOT = Path(__file__).resolve().parents[1]


def identify_with(track, passages) -> tuple[float, object]:
    """(seconds, Identification) of ``passages`` with the corrections on ``track``."""
    from wfjax.identify import forward as fwd
    from wfjax.identify import identify

    kept = fwd.CORRECTION_TRACK
    fwd.CORRECTION_TRACK = track
    try:
        t0 = time.perf_counter()
        res = identify(passages)
        return time.perf_counter() - t0, res
    finally:
        fwd.CORRECTION_TRACK = kept


def wheel_summary(res) -> np.ndarray:
    """[n_wheels, 3]: length median [mm], P(l >= the flag length), misfit (0/1)."""
    rows = [r.row() for r in res.wheels]
    return np.array([[r["length_median_mm"], r["p_flag"], float(r["misfit"])] for r in rows])


def run(args) -> dict:
    from wfjax.cli import enable_compilation_cache
    from wfjax.identify import forward as fwd

    # as `wfjax identify` and the study: a compiled batch dropped at forward's bound reloads
    enable_compilation_cache()

    tracks = {"70 bays": fwd.TRACK, "least": fwd.CORRECTION_TRACK}
    rows = []
    for n, w in enumerate(int(a) for a in args.wagons.split(",")):
        passages, _ = kept_passages(args.passages, w - 1)
        order = list(tracks) if n % 2 == 0 else list(tracks)[::-1]
        secs, summ = {k: [] for k in tracks}, {}
        first = {}
        for name in order:
            first[name], _ = identify_with(tracks[name], passages)  # its programs compiled
            for _ in range(args.rounds):
                t, res = identify_with(tracks[name], passages)
                secs[name].append(t)
                summ[name] = wheel_summary(res)
        diff = np.abs(summ["least"] - summ["70 bays"]).max(axis=0)
        rows.append({"wagon": w, "seconds": secs, "first_seconds": first,
                     "max_length_median_diff_mm": diff[0],
                     "max_p_flag_diff": diff[1], "misfit_changed": bool(diff[2] > 0)})
        print(f"wagon {w}: 70 bays {np.median(secs['70 bays']):.1f} s, least "
              f"{np.median(secs['least']):.1f} s; length medians within {diff[0]:.2f} mm, "
              f"P(flag) within {diff[1]:.3f}", flush=True)
    ratio = [np.median(r["seconds"]["least"]) / np.median(r["seconds"]["70 bays"])
             for r in rows]
    return {"rows": rows, "median_ratio": float(np.median(ratio)),
            "median_seconds_least": float(np.median([np.median(r["seconds"]["least"])
                                                     for r in rows])),
            "median_seconds_70": float(np.median([np.median(r["seconds"]["70 bays"])
                                                  for r in rows]))}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passages", required=True, help="the study's kept passages (folder)")
    ap.add_argument("--wagons", default="1,19,22,29,55", help="study wagons (from 1)")
    ap.add_argument("--rounds", type=int, default=1,
                    help="timed identifications each way per wagon")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/"
                                         "identify_correction_track.json"))
    args = ap.parse_args(argv)
    out = run(args) | {"date": time.strftime("%Y-%m-%d"), "argv": vars(args)}
    Path(args.out).write_text(json.dumps(out, indent=1, default=float))
    print(f"median ratio least / 70 bays {out['median_ratio']:.2f}; median per wagon "
          f"{out['median_seconds_least']:.1f} s against {out['median_seconds_70']:.1f} s")


if __name__ == "__main__":
    main()

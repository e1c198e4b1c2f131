"""The identification's passage time, old settings against new, in one process (issue 31,
docs/identify.md "Speed"): study wagons of the Hertz study's kept passages identified
alternately both ways, nothing else changed. ``--compare``:

- ``track``: the neighbour corrections on the 70-bay ``forward.TRACK`` (before 2026-12-05,
  night) against the same track at its least length with absorbing ends (the guards
  lengthen it to 36 bays; the corrections' track until 2026-12-06), 8 configurations per
  neighbour both ways;
- ``ends``: that absorbing least track against ``forward.CORRECTION_TRACK`` (end networks,
  24 bays; since 2026-12-06), 8 configurations both ways;
- ``phase-modes``: a neighbour's correction averaged over 8 configurations
  (``pipeline.PHASE_MODES``) against 16 (``--phase-modes 16``), both on ``CORRECTION_TRACK``;
- ``networks16``: the identification of 2026-12-05 (absorbing least track, 8
  configurations) against end networks with 16 (a default tried 2026-12-06, not kept);
- ``refine``: 8 configurations on ``CORRECTION_TRACK`` without and with a wheel in doubt
  corrected again over 16 (``pipeline.in_doubt``; the default since 2026-12-06).

The ways before ``refine`` correct no wheel again (as when they were measured).

Per wagon and way (the order alternates): one identification that compiles what it needs
(its seconds kept as ``first_seconds``), then ``--rounds`` timed ones with the programs
compiled, as in a study or a wayside service; and the largest difference of any wheel's
length median [mm], P(flag) and misfit.

    python benchmarks/identify_ab.py --compare phase-modes --passages DIR --wagons 1,19,22,29,55

Writes ``benchmarks/results/identify_ab_<compare>.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from identify_study import kept_passages  # benchmarks/, the script's folder

ROOT = Path(__file__).resolve().parents[1]
# way name -> (the corrections' track: a forward attribute or ABSORBING, phase_modes, a wheel
# in doubt corrected again); old way first
ABSORBING = "absorbing least"
NET = "CORRECTION_TRACK"
COMPARISONS = {"track": {"70 bays": ("TRACK", 8, False), ABSORBING: (ABSORBING, 8, False)},
               "ends": {ABSORBING: (ABSORBING, 8, False), "networks": (NET, 8, False)},
               "phase-modes": {"8": (NET, 8, False), "16": (NET, 16, False)},
               "networks16": {"absorbing, 8": (ABSORBING, 8, False),
                              "networks, 16": (NET, 16, False)},
               "refine": {"8": (NET, 8, False), "8, refined in doubt": (NET, 8, True)}}


def correction_track(name: str):
    """The corrections' track named ``name`` (:data:`COMPARISONS`)."""
    import dataclasses

    from wfjax.identify import forward as fwd

    if name == ABSORBING:
        return dataclasses.replace(fwd.TRACK, n_bays=4, ends="absorbing")
    return getattr(fwd, name)


def identify_with(way: tuple[str, int, bool], passages) -> tuple[float, object]:
    """(seconds, Identification) of ``passages`` with the corrections on ``forward``'s track
    named ``way[0]`` (:func:`correction_track`), ``phase_modes=way[1]``, and a wheel in doubt
    corrected again where ``way[2]`` (else the band of ``pipeline.in_doubt`` emptied)."""
    from wfjax.identify import forward as fwd
    from wfjax.identify import identify, pipeline

    kept = fwd.CORRECTION_TRACK, pipeline.REFINE_BELOW, pipeline.REFINE_ABOVE
    fwd.CORRECTION_TRACK = correction_track(way[0])
    if not way[2]:
        pipeline.REFINE_BELOW = pipeline.REFINE_ABOVE = -1.0
    try:
        t0 = time.perf_counter()
        res = identify(passages, phase_modes=way[1])
        return time.perf_counter() - t0, res
    finally:
        fwd.CORRECTION_TRACK, pipeline.REFINE_BELOW, pipeline.REFINE_ABOVE = kept


def wheel_summary(res) -> np.ndarray:
    """[n_wheels, 3]: length median [mm], P(l >= the flag length), misfit (0/1)."""
    rows = [r.row() for r in res.wheels]
    return np.array([[r["length_median_mm"], r["p_flag"], float(r["misfit"])] for r in rows])


def run(args) -> dict:
    from wfjax.cli import enable_compilation_cache

    # as `wfjax identify` and the study: a compiled batch dropped at forward's bound reloads
    enable_compilation_cache()
    ways = COMPARISONS[args.compare]
    old, new = list(ways)
    rows = []
    for n, w in enumerate(int(a) for a in args.wagons.split(",")):
        passages, _ = kept_passages(args.passages, w - 1)
        secs, summ, first = {k: [] for k in ways}, {}, {}
        for name in (ways if n % 2 == 0 else list(ways)[::-1]):
            first[name], _ = identify_with(ways[name], passages)  # its programs compiled
            for _ in range(args.rounds):
                t, res = identify_with(ways[name], passages)
                secs[name].append(t)
                summ[name] = wheel_summary(res)
        diff = np.abs(summ[new] - summ[old]).max(axis=0)
        rows.append({"wagon": w, "seconds": secs, "first_seconds": first,
                     "max_length_median_diff_mm": diff[0],
                     "max_p_flag_diff": diff[1], "misfit_changed": bool(diff[2] > 0)})
        print(f"wagon {w}: {old} {np.median(secs[old]):.1f} s, {new} "
              f"{np.median(secs[new]):.1f} s; length medians within {diff[0]:.2f} mm, "
              f"P(flag) within {diff[1]:.3f}", flush=True)
    per_way = {k: float(np.median([np.median(r["seconds"][k]) for r in rows])) for k in ways}
    ratio = [np.median(r["seconds"][new]) / np.median(r["seconds"][old]) for r in rows]
    return {"rows": rows, "ways": {k: list(v) for k, v in ways.items()},
            "median_ratio_new_to_old": float(np.median(ratio)),
            "median_seconds_per_wagon": per_way}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--compare", choices=list(COMPARISONS), default="phase-modes")
    ap.add_argument("--passages", required=True, help="the study's kept passages (folder)")
    ap.add_argument("--wagons", default="1,19,22,29,55", help="study wagons (from 1)")
    ap.add_argument("--rounds", type=int, default=1,
                    help="timed identifications each way per wagon")
    ap.add_argument("--out", help="default benchmarks/results/identify_ab_<compare>.json")
    args = ap.parse_args(argv)
    out = run(args) | {"date": time.strftime("%Y-%m-%d"), "argv": vars(args)}
    path = args.out or ROOT / "benchmarks/results" / f"identify_ab_{args.compare}.json"
    Path(path).write_text(json.dumps(out, indent=1, default=float))
    old, new = COMPARISONS[args.compare]
    secs = out["median_seconds_per_wagon"]
    print(f"median ratio {new} / {old}: {out['median_ratio_new_to_old']:.2f}; median per "
          f"wagon {secs[new]:.1f} s against {secs[old]:.1f} s")


if __name__ == "__main__":
    main()

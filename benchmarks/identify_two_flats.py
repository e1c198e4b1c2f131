"""How a wheel's own flat and its bogie neighbour's join in the detector's gated peak (issue 31,
docs/identify.md "Two flats in a bogie"): for every bogie of the Hertz study's kept passages
with a flat on both wheels, the identification's runs (``coupled_batch``, its track and
roughness) of the bogie with both flats at their true impacts against each wheel's own
flat with its neighbour round, and the neighbour's effect (the wheel round beside the
neighbour's flat, minus both round) joined to it by the two bounds of a gated peak of two
events (:func:`joined`): the sum, as the identification adds its corrections (the peaks
coincide), and the larger event (they do not). Per wheel-passage the largest relative
error over the bays of each rule and of the better of the two.

    python benchmarks/identify_two_flats.py --passages DIR

Writes ``benchmarks/results/identify_two_flats.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from identify_study import kept_passages  # benchmarks/, the script's folder

ROOT = Path(__file__).resolve().parents[1]


def joined(own, round_own, c) -> tuple[np.ndarray, np.ndarray]:
    """A wheel's readings [n_bays] N with a neighbour's effect ``c`` (coupled minus alone,
    the wheel round) given its own ``own`` and a round wheel's ``round_own``: (the sum
    ``own + c``, the larger event ``max(own + min(c, 0), round_own + c)``: a negative effect
    lowers both; for a round wheel both are round + effect)."""
    return own + c, np.maximum(own + np.minimum(c, 0.0), round_own + c)


def bogie_rows(k: int, passages, truths, pair: list[int]) -> list[dict]:
    """Per passage and wheel of bogie ``pair`` (both flat) of wagon ``k``: each rule's
    largest relative error over the bays against the coupled run of both flats."""
    from wfjax.identify import forward as fwd
    from wfjax.identify.pipeline import correction_roughness
    from wfjax.params import Wheel

    radius = float(Wheel().radius)
    rw = fwd.round_wheel(radius)
    rows = []
    for p, truth in zip(passages, truths, strict=True):
        fl = [fwd.flat_of(truth[j]["kind"], truth[j]["length"], truth[j].get("factor") or 1.0,
                          radius) for j in pair]
        x = [truth[j]["impact"] for j in pair]
        out, _ = fwd.coupled_batch([(fl, x), ([fl[0], rw], x), ([rw, fl[1]], x), ([rw, rw], x)],
                                   [0.0, 2.5], p.speed, p.detector(),
                                   roughness=correction_roughness())
        both, first, second, none = out
        for j, own, beside in ((0, first[0], second[0]), (1, second[1], first[1])):
            err = [float(np.max(np.abs(r - both[j]) / both[j]))
                   for r in joined(own, none[j], beside - none[j])]
            rows.append({"wagon": k, "wheel": pair[j], "speed_kmh": round(p.speed * 3.6),
                         "sum": err[0], "larger": err[1], "better": min(err)})
            print(f"wagon {k + 1} wheel {pair[j]} {p.speed * 3.6:.0f} km/h: sum "
                  f"{err[0] * 100:.1f} %, larger {err[1] * 100:.1f} %", flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passages", required=True, metavar="DIR")
    ap.add_argument("--wagons", type=int, default=63)
    args = ap.parse_args()
    rows, t0 = [], time.perf_counter()
    for k in range(args.wagons):
        try:
            passages, truths = kept_passages(args.passages, k)
        except FileNotFoundError:  # a study kept in part
            continue
        for pair in ([0, 1], [2, 3]):
            if all(truths[0][j]["length"] > 0 for j in pair):
                rows += bogie_rows(k, passages, truths, pair)
    summary = {rule: {q: float(np.quantile([r[rule] for r in rows], q)) for q in (0.5, 0.9, 1.0)}
               for rule in ("sum", "larger", "better")}
    print(json.dumps(summary, indent=1))
    out = {"date": time.strftime("%Y-%m-%d"), "wall_s": time.perf_counter() - t0,
           "n": len(rows), "summary": summary, "rows": rows}
    (ROOT / "benchmarks" / "results" / "identify_two_flats.json").write_text(
        json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()

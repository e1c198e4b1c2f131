"""How far a flat wheel's phase posterior lies from where its flat truly struck (issue 31,
docs/identify.md "Neighbour phase"): the identification's first pass (site factors, every
wheel on its own grid, no neighbour corrections: the posterior the corrections are built
from) on the Hertz study's kept passages, per flat wheel and passage:

- the error of the most probable impact coordinate, modulo the circumference [m];
- the posterior's mass within 1, 2, 5 and 10 cm of the true impact;
- the posterior's rank of the truth: P(|x - mode| <= |truth - mode|), uniform on [0, 1]
  for a calibrated phase posterior;

and, for each width of a periodic Gaussian blur of the posterior
(:func:`wfjax.identify.pipeline.blur_phase`), the mean log probability the blurred
posterior gives the truth's grid point, and the blurred ranks' distance from uniform
(Kolmogorov-Smirnov) and quantiles: the width whose ranks are closest to uniform is the phase
error the neighbour corrections assume (``pipeline.PHASE_ERROR``). The log score keeps
rising with the width because of the posteriors whose mode is another bay's (a third of the
rows lie over 20 cm off): it is shown, not used.

    python benchmarks/identify_phase_error.py --passages DIR [--wagons 63]

Writes ``benchmarks/results/identify_phase_error.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
from identify_study import kept_passages  # benchmarks/, the script's folder

ROOT = Path(__file__).resolve().parents[1]
WITHIN = (0.01, 0.02, 0.05, 0.10)  # m
SIGMAS = (0.0, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.07, 0.08, 0.10, 0.15, 0.20)  # m


def wrap(dx, circ: float):
    """``dx`` [m] taken to (-circ / 2, circ / 2]."""
    return (np.asarray(dx, float) + circ / 2) % circ - circ / 2


def rank(x, wt, truth: float, circ: float) -> float:
    """P(|x - mode| <= |truth - mode|) under the phase posterior ``wt`` on ``x`` [m]."""
    mode = x[int(np.argmax(wt))]
    err = abs(float(wrap(mode - truth, circ)))
    return float(wt[np.abs(wrap(x - mode, circ)) <= err + 1e-9].sum())


def blur_table(posteriors: list, circ: float) -> list[dict]:
    """Per blur width [m] (:data:`SIGMAS`): the mean log probability of the truth's grid
    point, the ranks' Kolmogorov-Smirnov distance from uniform and their quantiles, under
    the blurred phase posteriors ``[(x, wt, truth)]``."""
    from wfjax.identify.pipeline import blur_phase

    out = []
    for sigma in SIGMAS:
        logp, ranks = [], []
        for x, wt, truth in posteriors:
            b = blur_phase(x, wt, sigma, circ)
            logp.append(np.log(max(b[int(np.argmin(np.abs(wrap(x - truth, circ))))], 1e-12)))
            ranks.append(rank(x, b, truth, circ))
        r = np.sort(ranks)
        ks = float(np.max(np.maximum(np.arange(1, r.size + 1) / r.size - r,
                                     r - np.arange(r.size) / r.size)))
        out.append({"sigma_m": sigma, "mean_log_p_truth": float(np.mean(logp)), "ks": ks,
                    "rank_quantiles": [float(np.quantile(ranks, q)) for q in (0.1, 0.5, 0.9)]})
    return out


def wheel_rows(k: int, passages, truths, res, circ: float,
               min_p_flat: float) -> tuple[list[dict], list]:
    """Per flat wheel (truth length > 0, P(l >= 15 mm) >= ``min_p_flat``) and passage of
    wagon ``k``: (its phase figures, its (grid [m], posterior, truth [m]))."""
    rows, keep = [], []
    for i, w in enumerate(res.wheels):
        if truths[0][i]["length"] <= 0 or w.post.p_length_at_least(0.015) < min_p_flat:
            continue
        for p in range(len(passages)):
            x, wt = np.asarray(w.post.phases[p]), np.asarray(w.post.phase_weights[p])
            wt = wt / wt.sum()
            mode = x[int(np.argmax(wt))]
            truth = float(truths[p][i]["impact"])
            err = float(wrap(mode - truth, circ))
            off = np.abs(wrap(x - truth, circ))
            keep.append((x, wt, truth))
            rows.append({"wagon": k, "wheel": i, "speed_kmh": round(passages[p].speed * 3.6),
                         "kind": truths[0][i]["kind"], "length_m": truths[0][i]["length"],
                         "p_flat": w.post.p_length_at_least(0.015), "error_m": err,
                         "rank": rank(x, wt, truth, circ)} | {f"mass_within_{d * 100:g}cm":
                                          float(wt[off <= d + 1e-9].sum()) for d in WITHIN})
    return rows, keep


def summary(rows: list[dict]) -> dict:
    """Quantiles of |error| and of the rank, the mean mass within each distance."""
    err = np.abs([r["error_m"] for r in rows])
    rank = np.array([r["rank"] for r in rows])
    return {"n": len(rows), "abs_error_quantiles_m": {
        q: float(np.quantile(err, q)) for q in (0.5, 0.68, 0.8, 0.9, 0.95)},
        "robust_sigma_m": float(1.4826 * np.median(err)),
        "rank_quantiles": {q: float(np.quantile(rank, q)) for q in (0.1, 0.5, 0.9)},
        "mean_mass_within": {f"{d * 100:g}cm": float(np.mean(
            [r[f"mass_within_{d * 100:g}cm"] for r in rows])) for d in WITHIN},
        "share_error_within": {f"{d * 100:g}cm": float(np.mean(err <= d + 1e-9))
                               for d in WITHIN}}


def main() -> None:
    from wfjax.identify import identify
    from wfjax.params import Wheel

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passages", required=True, metavar="DIR")
    ap.add_argument("--wagons", type=int, default=63)
    ap.add_argument("--min-p-flat", type=float, default=0.5,
                    help="only wheels with P(l >= 15 mm) at least this (the corrections')")
    args = ap.parse_args()
    circ = 2 * math.pi * float(Wheel().radius)
    rows, keep, t0 = [], [], time.perf_counter()
    for k in range(args.wagons):
        try:
            passages, truths = kept_passages(args.passages, k)
        except FileNotFoundError:  # a study kept in part
            continue
        new, posteriors = wheel_rows(k, passages, truths,
                                     identify(passages, coupling_iterations=0), circ,
                                     args.min_p_flat)
        rows += new
        keep += posteriors
        print(f"wagon {k + 1}: " + ", ".join(f"{r['wheel']}@{r['speed_kmh']} "
                                              f"{r['error_m'] * 100:+.1f} cm" for r in new),
              flush=True)
    out = {"date": time.strftime("%Y-%m-%d"), "wall_s": time.perf_counter() - t0,
           "summary": summary(rows), "blur": blur_table(keep, circ), "rows": rows}
    print(json.dumps(out["summary"], indent=1))
    for b in out["blur"]:
        print(f"blur {b['sigma_m'] * 100:4.0f} cm: mean log p(truth) "
              f"{b['mean_log_p_truth']:.3f}, KS {b['ks']:.3f}, rank quantiles 10/50/90 %",
              np.round(b["rank_quantiles"], 3))
    path = ROOT / "benchmarks" / "results" / "identify_phase_error.json"
    path.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()

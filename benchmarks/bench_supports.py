"""Modal model build of a track whose supports vary, against the uniform track.

Uncached builds (``use_cache=False``) in one process, interleaved and repeated; the figures
are the ratios of the best times, wall clock and process CPU time (which waits less on other
work on a shared machine). The issue's target: a scattered-support track builds in under
twice the uniform track's time. The uniform track splits into symmetric and antisymmetric
halves; a scattered one solves the full eigenproblem (only the modes kept), and tabulates the
static residual along the whole rail instead of across one bay.

Run: ``python benchmarks/bench_supports.py [--max-frequency 10000] [--repeats 3]``
(about a minute on 2 cores). Prints Markdown.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _tracks import RECORDED  # benchmarks/, the script's folder

import wfjax
from wfjax.model import supports as S
from wfjax.model import track as T


def timed(fn) -> tuple[float, float]:
    """(wall, process CPU) seconds of one call."""
    t0, c0 = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - t0, time.process_time() - c0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-frequency", type=float,
                    default=wfjax.SimConfig().resolved().track_max_frequency)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    base = wfjax.Track(**RECORDED)
    tracks = {
        "uniform (Table 2)": base,
        "scattered, cv 0.3 on k_P and k_B": S.scatter(base, 0, cv=0.3),
        "void under the middle sleeper (symmetric)": S.void_sleeper(base, base.n_bays // 2 - 1),
        "void 2 sleepers right of x = 0": S.void_sleeper(base, base.n_bays // 2 + 1),
    }
    T.modal_model(base, args.max_frequency, use_cache=False)  # warm BLAS/LAPACK and imports
    times = {name: [] for name in tracks}
    for _ in range(args.repeats):  # interleaved: load changes hit every track alike
        for name, tr in tracks.items():
            times[name].append(timed(
                lambda tr=tr: T.modal_model(tr, args.max_frequency, use_cache=False)))
    ref = np.array(times["uniform (Table 2)"]).min(axis=0)
    print(f"Modal model build, {base.n_bays} bays x {base.elements_per_bay} elements, modes "
          f"below {args.max_frequency:g} Hz, {args.repeats} repeats (uncached):\n")
    med = np.median(np.array(times["uniform (Table 2)"]), axis=0)
    print("| track | modes | residual points | wall best [s] | ratio | wall median [s] | ratio "
          "| CPU best [s] | ratio |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for name, tr in tracks.items():
        m = T.modal_model(tr, args.max_frequency, use_cache=False)
        t = np.array(times[name])
        wall, cpu = t.min(axis=0)
        wall_med = np.median(t[:, 0])
        print(f"| {name} | {m.poles.shape[0]} | {m.residual_x.shape[0]} | {wall:.2f} | "
              f"{wall / ref[0]:.2f} | {wall_med:.2f} | {wall_med / med[0]:.2f} | {cpu:.2f} | "
              f"{cpu / ref[1]:.2f} |")


if __name__ == "__main__":
    main()

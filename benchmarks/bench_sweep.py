"""Sweep benchmark: throughput vs batch size, scaling with the work, the default sweep's split.

Run: ``python benchmarks/bench_sweep.py [--default] [--scaling] [--png PATH]`` (both parts when
neither is given). Prints Markdown.

* ``--scaling``: Hertz-trajectory sweeps of the 0.9 mm rounded flat (speeds 50-250 km/h,
  each run in its own window: 2145-3614 steps). Throughput [simulations/s] against
  ``chunk_size``, and total time against the number of speeds, positions and flats with a
  log-log plot and the slope fitted beyond one compiled batch. Compile time (from
  ``jax.monitoring`` compile events) is reported apart; run times are the median of repeats
  with compiled code.
* ``--default``: the default ``wfjax sweep`` (rounded 0.9 mm/100 mm and new 0.9 mm flats,
  20-300 km/h in 10 km/h steps, 10 positions, 3D table contact) from a fresh
  ``WFJAX_CACHE_DIR`` (cold: modal model build, table builds, compilation, batched loop), then
  again in the same process (warm: modal model from disk, compiled program reused). The split
  comes from timing wrappers around ``structure`` (the modal model), ``cached_tables_3d``
  (the tables, built in a background thread while the modal model builds and the program
  compiles: these phases overlap and do not add up to the total) and ``_run_group`` (the
  batched loop), and the compile events.
"""

from __future__ import annotations

import argparse
import importlib
import os
import statistics
import tempfile
import time

import jax
import numpy as np

import wfjax as wf
from wfjax._compile_clock import compile_seconds

sweep_mod = importlib.import_module("wfjax.sweeps")  # the module (wfjax.sweep is the function)


ROUNDED = wf.Flat.rounded(depth=0.9e-3, length=0.1)


def timed_sweep(*args, **kwargs):
    """(result, wall [s], compile [s]) of one :func:`wfjax.sweep` call."""
    c0 = compile_seconds()
    t0 = time.perf_counter()
    res = wf.sweep(*args, progress=False, **kwargs)
    wall = time.perf_counter() - t0
    return res, wall, compile_seconds() - c0


def median_run(args, kwargs, repeats: int = 3) -> tuple[float, float]:
    """(compile [s] of the first call, median wall [s] of ``repeats`` compiled calls)."""
    _, _, comp = timed_sweep(*args, **kwargs)
    return comp, statistics.median(timed_sweep(*args, **kwargs)[1] for _ in range(repeats))


def speeds(n: int) -> np.ndarray:
    return np.linspace(50.0, 250.0, n) / 3.6


def scaling(png: str) -> None:
    contact = "hertz-trajectory"
    print(f"### Throughput against batch size ({contact}, 64 runs = 16 speeds x 4 positions)\n")
    print("| chunk_size | compile [s] | run (median of 3) [s] | simulations/s |")
    print("| --- | --- | --- | --- |")
    for chunk in (1, 4, 16, 64):
        comp, run = median_run((ROUNDED, speeds(16), 4), dict(contact=contact, chunk_size=chunk))
        print(f"| {chunk} | {comp:.2f} | {run:.3f} | {64 / run:.0f} |")
    chunk = 16
    print(f"\n### Total time against the work ({contact}, chunk_size = {chunk}; compiled)\n")
    print("| varied | runs | compile [s] | run (median of 3) [s] |")
    print("| --- | --- | --- | --- |")
    series = {}
    for n in (2, 4, 8, 16, 32, 64):
        comp, run = median_run((ROUNDED, speeds(n), 2), dict(contact=contact, chunk_size=chunk))
        series.setdefault("speeds (x 2 positions)", []).append((2 * n, run))
        print(f"| speeds | {2 * n} | {comp:.2f} | {run:.3f} |")
    for n in (2, 4, 8, 16, 32, 64):
        comp, run = median_run((ROUNDED, speeds(2), n), dict(contact=contact, chunk_size=chunk))
        series.setdefault("positions (x 2 speeds)", []).append((2 * n, run))
        print(f"| positions | {2 * n} | {comp:.2f} | {run:.3f} |")
    for n in (1, 2, 4, 8):
        flats = [wf.Flat.rounded(depth=d, length=0.1) for d in np.linspace(0.5e-3, 0.9e-3, n)]
        comp, run = median_run((flats, speeds(4), 4), dict(contact=contact, chunk_size=chunk))
        series.setdefault("flats (x 16 runs)", []).append((16 * n, run))
        print(f"| flats | {16 * n} | {comp:.2f} | {run:.3f} |")
    print()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4))
    for label, pts in series.items():
        n, t = np.array(pts).T
        beyond = n >= 2 * chunk
        slope = np.polyfit(np.log(n[beyond]), np.log(t[beyond]), 1)[0]
        print(f"- {label}: log-log slope {slope:.2f} for runs >= {2 * chunk}")
        ax.loglog(n, t, "o-", label=f"{label}: slope {slope:.2f}")
    ax.axvline(chunk, color="0.7", ls=":", label=f"one batch ({chunk} runs)")
    ax.set_xlabel("simulations in the sweep")
    ax.set_ylabel("wall time, compiled [s]")
    ax.set_title(f"wfjax.sweep scaling ({contact})")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(png, dpi=120)
    print(f"\nPlot: {png}")


def default_sweep() -> None:
    cache = tempfile.mkdtemp(prefix="wfjax_bench_cold_")
    os.environ["WFJAX_CACHE_DIR"] = cache
    split = {"structure": 0.0, "tables": 0.0, "loop": 0.0}

    def wrap(name, fn):
        def inner(*a, **k):
            t0 = time.perf_counter()
            out = jax.block_until_ready(fn(*a, **k))
            split[name] += time.perf_counter() - t0
            return out
        return inner

    sweep_mod.structure = wrap("structure", sweep_mod.structure)
    sweep_mod.cached_tables_3d = wrap("tables", sweep_mod.cached_tables_3d)
    sweep_mod._run_group = wrap("loop", sweep_mod._run_group)
    flats = [ROUNDED, wf.Flat.new(depth=0.9e-3)]
    v = np.arange(20.0, 301.0, 10.0) / 3.6
    print(f"### Default sweep (2 flats x {v.size} speeds x 10 positions, 3d), cache {cache}\n")
    print("| run | total [s] | modal model [s] | tables, in the background [s] | compilation "
          "(CPU, all threads) [s] | batched loop [s] |")
    print("| --- | --- | --- | --- | --- | --- |")
    for label in ("cold (fresh cache dir, new process)", "warm (same process, again)"):
        split.update(structure=0.0, tables=0.0, loop=0.0)
        res, wall, comp = timed_sweep(flats, v, 10, contact="3d")
        print(f"| {label} | {wall:.1f} | {split['structure']:.1f} | {split['tables']:.1f} | "
              f"{comp:.1f} | {split['loop']:.1f} |")
    env = res.envelope()
    print(f"\npeak max force [kN]: rounded {env['max_force'][0].max() / 1e3:.1f}, new "
          f"{env['max_force'][1].max() / 1e3:.1f}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--default", action="store_true")
    p.add_argument("--scaling", action="store_true")
    p.add_argument("--png", default="benchmarks/sweep_scaling.png")
    a = p.parse_args()
    both = not (a.default or a.scaling)
    print(f"devices: {jax.devices()}, x64: {jax.config.jax_enable_x64}\n")
    if a.scaling or both:
        scaling(a.png)
    if a.default or both:
        default_sweep()


if __name__ == "__main__":
    main()

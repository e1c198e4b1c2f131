"""The default sweep's run-steps, needed and computed, and its warm time, old layout against new.

Issue 33, item 2: "1.83 M computed for 1.66 M needed". Every device's batched loop runs its
lanes to its longest run, in whole blocks of ``LOOP_BLOCK`` (128) steps, so a device's share
of a chunk computes ``lanes x loop_steps(longest)`` run-steps (``wfjax.program.grid.run_steps``).

* ``--count [--sweep-args "FLAGS"]``: the default ``wfjax sweep`` case (or ``wfjax sweep
  FLAGS``) on ``--devices`` CPU devices (default one per
  core, as the command): runs, chunks, run-steps needed and computed with this tree's
  ``lane_layout``, and with the layout before it (every device took every n-th run of its
  chunk, so each share spanned the chunk's whole range of step counts; the padding repeated
  the chunk's last, longest run), recomputed here from the same plan.
* ``--loop``: the default sweep in one process (``wfjax.sweep``, warm: modal model, tables
  and program reused), the layout before (``dealt_layout``) and ``lane_layout`` in turn over
  ``--rounds`` rounds after an unrecorded warm-up: wall and CPU seconds (all threads), the
  paired median ratios and the largest relative difference of the results.
* ``--old TREE --new TREE``: the warm ``wfjax sweep`` (whole process) of each tree
  (``PYTHONPATH=TREE``, its own ``WFJAX_CACHE_DIR``, warmed by one unrecorded run),
  interleaved over ``--rounds`` rounds (old first in even rounds, new first in odd ones):
  wall and CPU (user + system) seconds, their medians and the paired median ratio new/old;
  the last round's ``sweep.npz`` arrays compared (largest relative difference).

Run: ``python benchmarks/bench_padding.py --count`` and ``python benchmarks/bench_padding.py
--old /tmp/old --new /tmp/new --rounds 5`` (trees: ``git worktree add --detach``).
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _old_run_steps(runs) -> int:
    """Run-steps computed by the layout before ``lane_layout``: each chunk of ``step`` sorted
    runs, padded to ``width`` by repeating its last run, dealt to the devices in turn."""
    import numpy as np

    from wfjax.program.grid import _END_STEPS, loop_steps

    ends = runs.columns[_END_STEPS]
    share = runs.width // runs.n_devices
    total = 0
    for lo in range(0, ends.size, runs.step):
        chunk = ends[lo:lo + runs.step]
        chunk = np.concatenate([chunk, np.repeat(chunk[-1:], runs.width - chunk.size)])
        total += sum(share * int(loop_steps(chunk[d::runs.n_devices].max()))
                     for d in range(runs.n_devices))
    return total


def count(n_devices: int, sweep_args: list[str]) -> None:
    """Print the plan and run-steps of ``wfjax sweep *sweep_args`` (see the module
    docstring)."""
    os.environ["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={n_devices}"
    from wfjax.cli import build_parser, enable_compilation_cache
    from wfjax.commands._common import resolve_case
    from wfjax.program import grid
    from wfjax.program.core import compile_scenario
    from wfjax.program.laws import batch_groups
    from wfjax.scenario.description import Scenario

    enable_compilation_cache()
    case = resolve_case(build_parser().parse_args(["sweep", *sweep_args]), "sweep")
    wheel, track, material, config = case.model()
    sc = Scenario.of(case.flats(), case["run.contact"], wheel=wheel, track=track,
                     material=material, config=config)
    v, pos = sc.speeds(case.speeds()), sc.positions(case["run.impact_positions"])
    program = compile_scenario(sc)
    mesh = grid.device_mesh()
    print("| group | runs | chunks x lanes | needed [M] | computed, before [M] | "
          "computed, now [M] |")
    print("| --- | --- | --- | --- | --- | --- |")
    for group in batch_groups(sc.flats, sc.contact, sc.config):
        windows = [sc.window_flat(sc.flats[i]) for i in group.indices]
        runs = grid.plan_runs(windows, v, pos + sc.shift, program.data.struct, sc.config,
                              mesh, None, sc.n_realisations)
        needed, computed = grid.run_steps(runs)
        print(f"| {list(group.indices)} | {runs.columns[0].size} | {runs.n_chunks} x "
              f"{runs.n_devices} x {runs.width // runs.n_devices} | {needed / 1e6:.3f} | "
              f"{_old_run_steps(runs) / 1e6:.3f} | {computed / 1e6:.3f} |")


def dealt_layout(ends, n_chunks: int, width: int, n_devices: int):
    """The layout before :func:`wfjax.program.grid.lane_layout`, as its (lanes, real): chunks
    of ``step = ceil(n / n_chunks)`` sorted runs, each padded to ``width`` by repeating its
    last run, dealt to the devices in turn."""
    import numpy as np

    n = ends.size
    step = -(-n // n_chunks)
    lanes, real = [], []
    for lo in range(0, n, step):
        runs = np.arange(lo, min(lo + step, n))
        runs = np.concatenate([runs, np.repeat(runs[-1:], width - runs.size)])
        is_real = np.arange(width) < min(step, n - lo)
        lanes += [runs[d::n_devices] for d in range(n_devices)]
        real += [is_real[d::n_devices] for d in range(n_devices)]
    return np.concatenate(lanes), np.concatenate(real)


def loop(n_devices: int, rounds: int) -> None:
    """Print the default sweep's warm in-process time (wall, and CPU of all threads) with
    the dealt layout and with ``lane_layout``, interleaved in one process."""
    os.environ["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={n_devices}"
    import numpy as np
    from _timing import FLATS, SPEEDS

    import wfjax as wf
    from wfjax.program import grid

    layouts = {"dealt": dealt_layout, "lanes": grid.lane_layout}
    times, results = {k: [] for k in layouts}, {}
    for r in range(rounds + 1):  # round 0: compile and warm, not recorded
        for name in (list(layouts) if r % 2 == 0 else list(layouts)[::-1]):
            grid.lane_layout = layouts[name]
            c0, t0 = time.process_time(), time.perf_counter()
            res = wf.sweep(FLATS, SPEEDS, 10, progress=False)
            if r:
                times[name].append((time.perf_counter() - t0, time.process_time() - c0))
            results[name] = np.stack([res.max_force, res.min_force, res.axle_acc_peak])
    grid.lane_layout = layouts["lanes"]
    for name, t in times.items():
        print(f"| {name} | {', '.join(f'{w:.2f}' for w, _ in t)} | "
              f"{statistics.median(w for w, _ in t):.2f} | "
              f"{statistics.median(c for _, c in t):.2f} |")
    for i, what in enumerate(("wall", "CPU")):
        ratio = statistics.median(n[i] / o[i] for o, n in zip(*times.values(), strict=True))
        print(f"\npaired median ratio lanes/dealt, {what}: {ratio:.3f}")
    a, b = results["dealt"], results["lanes"]
    worst = np.max(np.abs(b - a) / np.maximum(np.abs(a), 1e-300))
    print(f"largest relative difference (max, min force, axle-box peak): {worst:.1e}")


def _cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _sweep(tree: Path, cache: Path, work: Path) -> tuple[float, float]:
    """(wall [s], CPU [s]) of one ``wfjax sweep`` of ``tree`` in ``work``."""
    env = dict(os.environ, PYTHONPATH=str(tree), WFJAX_CACHE_DIR=str(cache))
    env.pop("XLA_FLAGS", None)
    cli = Path(sys.executable).with_name("wfjax")
    c0, t0 = _cpu_children(), time.perf_counter()
    subprocess.run([str(cli), "sweep"], env=env, cwd=work, check=True, capture_output=True)
    return time.perf_counter() - t0, _cpu_children() - c0


def differences(a: Path, b: Path) -> dict[str, float]:
    """Per float array of two ``sweep.npz``: the largest difference relative to each value
    (``max_residual``, the contact's Newton residual, itself roundoff of ~1e-15 m: the largest
    absolute difference [m]); other arrays must be equal."""
    import numpy as np

    out = {}
    with np.load(a) as x, np.load(b) as y:
        for k in x.files:
            if x[k].dtype.kind != "f" or not x[k].size:
                assert np.array_equal(x[k], y[k]), k
                continue
            scale = 1.0 if k == "max_residual" else np.abs(x[k])
            out[k] = float(np.max(np.abs(x[k] - y[k]) / np.maximum(scale, 1e-300)))
    return out


def timing(trees: dict[str, Path], rounds: int) -> None:
    """Print the interleaved warm times of ``trees`` (see the module docstring)."""
    base = Path(tempfile.mkdtemp(prefix="wfjax-padding-"))
    dirs = {k: (base / k / "cache", base / k / "work") for k in trees}
    for name, tree in trees.items():
        for d in dirs[name]:
            d.mkdir(parents=True)
        _sweep(tree, *dirs[name])  # cold: builds the caches, not recorded
    times = {k: [] for k in trees}
    for r in range(rounds):
        for name in (list(trees) if r % 2 == 0 else list(trees)[::-1]):
            times[name].append(_sweep(trees[name], *dirs[name]))
            print(f"round {r + 1} {name}: {times[name][-1][0]:.2f} s wall, "
                  f"{times[name][-1][1]:.2f} s CPU, load {os.getloadavg()[0]:.1f}",
                  file=sys.stderr)
    print("| tree | warm wall [s] | median | CPU median [s] |")
    print("| --- | --- | --- | --- |")
    for name, t in times.items():
        print(f"| {name} | {', '.join(f'{w:.2f}' for w, _ in t)} | "
              f"{statistics.median(w for w, _ in t):.2f} | "
              f"{statistics.median(c for _, c in t):.2f} |")
    old, new = (times[k] for k in trees)
    for i, what in enumerate(("wall", "CPU")):
        ratio = statistics.median(n[i] / o[i] for o, n in zip(old, new, strict=True))
        print(f"\npaired median ratio new/old, {what}: {ratio:.3f}")
    out = [dirs[k][1] / "out" / "sweep" / "sweep.npz" for k in trees]
    print("largest relative differences of the results: " + ", ".join(
        f"{k} {v:.1e}" for k, v in differences(*out).items()))


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--count", action="store_true", help="count the default sweep's run-steps")
    p.add_argument("--devices", type=int, default=os.cpu_count() or 1)
    p.add_argument("--sweep-args", default="", help="flags of the counted wfjax sweep "
                   "(default none: the default sweep)")
    p.add_argument("--old", type=Path, help="tree of the old code")
    p.add_argument("--new", type=Path, help="tree of the new code")
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--loop", action="store_true",
                   help="in-process warm sweep, dealt layout against lane_layout")
    args = p.parse_args(argv)
    if args.count:
        count(args.devices, args.sweep_args.split())
    if args.loop:
        loop(args.devices, args.rounds)
    if args.old and args.new:
        timing({"old": args.old, "new": args.new}, args.rounds)


if __name__ == "__main__":
    main()

"""The default sweep's run-steps, needed and computed, and its warm time, old layout against new.

Issue 33, item 2: "1.83 M computed for 1.66 M needed". Every device's batched loop runs its
lanes to its longest run, in whole blocks of ``LOOP_BLOCK`` (128) steps, so a device's share
of a chunk computes ``lanes x loop_steps(longest)`` run-steps (``wfjax.program.grid.run_steps``).

* ``--count``: the default ``wfjax sweep`` case on ``--devices`` CPU devices (default one per
  core, as the command): runs, chunks, run-steps needed and computed with this tree's
  ``lane_layout``, and with the layout before it (every device took every n-th run of its
  chunk, so each share spanned the chunk's whole range of step counts; the padding repeated
  the chunk's last, longest run), recomputed here from the same plan.
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


def count(n_devices: int) -> None:
    """Print the default sweep's plan and run-steps (see the module docstring)."""
    os.environ["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={n_devices}"
    from wfjax.cli import build_parser, enable_compilation_cache
    from wfjax.commands._common import resolve_case
    from wfjax.program import grid
    from wfjax.program.core import compile_scenario
    from wfjax.program.laws import batch_groups
    from wfjax.scenario.description import Scenario

    enable_compilation_cache()
    case = resolve_case(build_parser().parse_args(["sweep"]), "sweep")
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


def _largest_difference(a: Path, b: Path) -> float:
    """Largest relative difference between the float arrays of two ``sweep.npz``."""
    import numpy as np

    worst = 0.0
    with np.load(a) as x, np.load(b) as y:
        for k in x.files:
            if x[k].dtype.kind == "f":
                scale = np.maximum(np.abs(x[k]), 1e-300)
                worst = max(worst, float(np.max(np.abs(x[k] - y[k]) / scale)))
            else:
                assert np.array_equal(x[k], y[k]), k
    return worst


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
    print(f"largest relative difference of the results: {_largest_difference(*out):.1e}")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--count", action="store_true", help="count the default sweep's run-steps")
    p.add_argument("--devices", type=int, default=os.cpu_count() or 1)
    p.add_argument("--old", type=Path, help="tree of the old code")
    p.add_argument("--new", type=Path, help="tree of the new code")
    p.add_argument("--rounds", type=int, default=5)
    args = p.parse_args(argv)
    if args.count:
        count(args.devices)
    if args.old and args.new:
        timing({"old": args.old, "new": args.new}, args.rounds)


if __name__ == "__main__":
    main()

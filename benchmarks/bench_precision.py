"""float32 against float64, and this tree against an older one, in interleaved rounds.

Issue 33, item 3 ("float32 where it pays"). One worker process per variant (tree x
precision x job), each compiled and warmed once; then ``--rounds`` rounds, each timing one
call of every worker in turn (the order rotates from round to round), so every variant sees
the same drift of this shared machine and the ratios are paired medians over the rounds.

Jobs (``--jobs``):

* ``loop``: the batched time loop alone, ``jax.vmap`` of :func:`wfjax.loop.run.time_loop`
  over ``--batch`` runs (speeds spread over 20-80 m/s, the rounded 0.9 mm/100 mm flat,
  ``--contact``, dt = 10 us, ``--steps`` steps), compiled with ``loop_compiler_options()`` on
  one CPU device: the per-run-step cost in us;
* ``sweep``: ``wfjax.sweep`` of the default ``wfjax sweep`` case (rounded 0.9 mm/100 mm and
  new 0.9 mm flats, 29 speeds 20-300 km/h, 10 positions, 3D tables, the default track), one
  CPU device per core as the command, warm (tables from the disk cache).

Wall and CPU (user + system) seconds of each call; on a loaded machine the CPU seconds
are the steadier measure of the work (the wall adds the time the process waits for a core).
Ratios are paired medians over the rounds: float32 / float64 of the same tree, and each tree /
the first (``--new``) in the same precision. Accuracy: every worker's max forces, float32
against float64 of the same tree and each tree against the first in the same precision
(largest relative difference over the runs).

``--newton-tol32 K`` (a what-if, not the code's behaviour): the float32 workers' scalar
contact Newton (:func:`wfjax.contact.newton.bracketed_newton`) stops at
|r| <= max(1e-15 m, K eps32 |delta_free|) instead of 1e-15 m, which float32 cannot reach.

Run: ``python benchmarks/bench_precision.py --old /tmp/old [--jobs loop,sweep] [--batch 64]
[--rounds 7] [--json out.json]`` (``--old``: a ``git worktree add --detach /tmp/old REV``;
without it only this tree runs). Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

from _tracks import RECORDED  # benchmarks/, the script's folder

HERE = Path(__file__).resolve()
PRECISIONS = ("float64", "float32")


# ---------------------------------------------------------------- worker (one variant)

def _patch_newton(k: float) -> None:
    """float32 Newton stops at max(tol, k eps32 |delta_free|) (the ``--newton-tol32`` what-if)."""
    import jax.numpy as jnp

    from wfjax.contact import newton
    original = newton.bracketed_newton

    def patched(evaluate, delta_free, compliance, aux0, max_iter=30, tol=1e-15):
        if jnp.asarray(delta_free).dtype == jnp.float32:
            tol = jnp.maximum(tol, k * jnp.finfo(jnp.float32).eps * jnp.abs(delta_free))
        return original(evaluate, delta_free, compliance, aux0, max_iter, tol)

    newton.bracketed_newton = patched


def _loop_job(precision: str, args):
    """() -> max force [batch] N of one call of the batched loop (compiled here)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import wfjax as wf
    from wfjax._xla import loop_compiler_options
    from wfjax.contact.laws import prepare
    from wfjax.loop.run import time_loop
    from wfjax.loop.structure import structure
    from wfjax.model.vehicle import Vehicle

    config = wf.SimConfig(precision=precision)
    flat = wf.Flat.rounded(depth=0.9e-3, length=0.1)
    struct = structure(Vehicle.single(), [wf.Wheel()], wf.Track(**RECORDED), config)
    law = prepare(args.contact, flat, wf.Wheel(), wf.Track(**RECORDED), wf.Material(), config)
    speeds = jnp.linspace(20.0, 80.0, args.batch)

    def batch(law, struct, v):
        return jax.vmap(lambda vi: time_loop(law, struct, vi, 1e-5, -0.3, 0.1, args.steps,
                                             precision=precision)["force"].max())(v)

    compiled = jax.jit(batch, compiler_options=loop_compiler_options()).lower(
        law, struct, speeds).compile()
    return lambda: np.asarray(compiled(law, struct, speeds))


def _sweep_job(precision: str, args):
    """() -> max force [runs] N of the default sweep case (warm after the first call)."""
    import numpy as np

    import wfjax as wf
    from wfjax.commands.figures import fig7_flats

    speeds = np.linspace(20.0, 300.0, 29) / 3.6
    config = wf.SimConfig(precision=precision)

    def run():
        res = wf.sweep(fig7_flats(), speeds, 10, contact="3d", config=config, progress=False)
        return np.asarray(res.max_force).ravel()

    return run


def worker(args) -> int:
    """Build the job, answer ``ready <max forces>``, then one timed call per ``run`` line."""
    if args.job == "sweep":
        from wfjax.cli import expose_cpu_cores
        expose_cpu_cores()
    if args.newton_tol32:
        _patch_newton(args.newton_tol32)
    call = (_loop_job if args.job == "loop" else _sweep_job)(args.precision, args)
    first = call()
    call()  # warm
    print("ready " + json.dumps([float(v) for v in first]), flush=True)
    for line in sys.stdin:
        if line.strip() != "run":
            break
        c0 = _cpu()
        t0 = time.perf_counter()
        call()
        print(f"{time.perf_counter() - t0} {_cpu() - c0}", flush=True)
    return 0


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


# ---------------------------------------------------------------- parent

def _start(tree: str, job: str, precision: str, args) -> subprocess.Popen:
    cmd = [sys.executable, str(HERE), "--worker", job, "--precision", precision,
           "--batch", str(args.batch), "--steps", str(args.steps), "--contact", args.contact]
    if args.newton_tol32:
        cmd += ["--newton-tol32", str(args.newton_tol32)]
    env = dict(os.environ, PYTHONPATH=tree)
    return subprocess.Popen(cmd, env=env, cwd="/tmp", stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)


def _ready(proc: subprocess.Popen) -> list[float]:
    line = proc.stdout.readline()
    if not line.startswith("ready "):
        raise RuntimeError(f"worker failed: {line!r}")
    return json.loads(line[6:])


def _max_rel(a, b) -> float:
    return max(abs(x / y - 1.0) for x, y in zip(a, b, strict=True))


def measure(trees: dict, args) -> dict:
    """Interleaved rounds over every (tree, job, precision): times, ratios, accuracy."""
    keys = [(t, j, p) for j in args.jobs for t in trees for p in PRECISIONS]
    procs, forces = {}, {}
    for key in keys:  # one at a time: compiles would fight for the cores
        procs[key] = _start(trees[key[0]], key[1], key[2], args)
        forces[key] = _ready(procs[key])
    times = {key: [] for key in keys}
    for r in range(args.rounds):
        order = keys[r % len(keys):] + keys[:r % len(keys)]
        for key in order:
            procs[key].stdin.write("run\n")
            procs[key].stdin.flush()
            wall, cpu = map(float, procs[key].stdout.readline().split())
            times[key].append((wall, cpu))
    for proc in procs.values():
        proc.stdin.close()
        proc.wait()
    return summarise(trees, keys, times, forces, args)


def _paired(times, key, ref, i: int = 0) -> float:
    """Median over the rounds of the ratio key / ref (same round) of wall (``i`` = 0) or CPU
    (1) seconds."""
    return statistics.median(a[i] / b[i] for a, b in zip(times[key], times[ref], strict=True))


def summarise(trees, keys, times, forces, args) -> dict:
    """Medians, paired median ratios (float32 / float64 of the same tree; each tree / the
    first in the same precision), accuracy (largest relative difference of the max force)."""
    first = next(iter(trees))
    rows = []
    for key in keys:
        tree, job, precision = key
        wall = [t[0] for t in times[key]]
        f64 = (tree, job, "float64")
        row = {"tree": tree, "job": job, "precision": precision, "runs": len(forces[key]),
               "median_s": statistics.median(wall),
               "cpu_s": statistics.median(t[1] for t in times[key]),
               "to_float64": _paired(times, key, f64),
               "to_first_tree": _paired(times, key, (first, job, precision)),
               "cpu_to_float64": _paired(times, key, f64, 1),
               "cpu_to_first_tree": _paired(times, key, (first, job, precision), 1),
               "f32_vs_f64": (_max_rel(forces[key], forces[f64])
                              if precision == "float32" else None),
               "vs_first_tree": _max_rel(forces[key], forces[(first, job, precision)])}
        if job == "loop":
            row["us_per_run_step"] = 1e6 * row["median_s"] / (row["runs"] * (args.steps - 1))
        rows.append(row)
    return {"rows": rows, "rounds": args.rounds, "batch": args.batch, "steps": args.steps,
            "contact": args.contact, "newton_tol32": args.newton_tol32,
            "load_after": os.getloadavg()[0], "date": time.strftime("%Y-%m-%d %H:%M UTC",
                                                                     time.gmtime())}


def markdown(result: dict) -> str:
    """The rows as a Markdown table (ratios: paired medians over the rounds)."""
    head = ("| tree | job | precision | runs | wall [s] | CPU [s] | us/run-step | / float64 "
            "(same tree), wall; CPU | / first tree (same precision), wall; CPU | f32 vs f64: "
            "max force | vs first tree: max force |\n"
            "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n")
    lines = []
    for r in result["rows"]:
        per = f"{r['us_per_run_step']:.2f}" if "us_per_run_step" in r else "-"
        f32 = "-" if r["f32_vs_f64"] is None else f"{r['f32_vs_f64']:.1e}"
        lines.append(f"| {r['tree']} | {r['job']} | {r['precision']} | {r['runs']} | "
                     f"{r['median_s']:.3f} | {r['cpu_s']:.3f} | {per} | "
                     f"{r['to_float64']:.2f}; {r['cpu_to_float64']:.2f} | "
                     f"{r['to_first_tree']:.2f}; {r['cpu_to_first_tree']:.2f} | {f32} | "
                     f"{r['vs_first_tree']:.1e} |")
    return head + "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--old", help="an older tree to compare (a git worktree)")
    p.add_argument("--new", default=str(HERE.parents[1]), help="this tree (default)")
    p.add_argument("--jobs", default="loop", help="loop,sweep")
    p.add_argument("--batch", type=int, default=64, help="runs of the loop job")
    p.add_argument("--steps", type=int, default=2000, help="steps of the loop job")
    p.add_argument("--contact", default="hertz-trajectory", help="contact of the loop job")
    p.add_argument("--rounds", type=int, default=7)
    p.add_argument("--newton-tol32", type=float, default=0.0, help="what-if, see above")
    p.add_argument("--json", help="write the result here")
    p.add_argument("--worker", help=argparse.SUPPRESS)
    p.add_argument("--precision", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.worker:
        args.job = args.worker
        return worker(args)
    args.jobs = args.jobs.split(",")
    trees = {"new": args.new} | ({"old": args.old} if args.old else {})
    result = measure(trees, args)
    print(markdown(result))
    print(f"batch {args.batch}, {args.steps} steps, {args.contact}, {args.rounds} rounds; "
          f"load after {result['load_after']:.1f}")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

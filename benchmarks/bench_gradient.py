"""Benchmark of the adjoint (issue 20 item 4): the reverse-mode gradient of a max-force misfit
through full 3D simulations, against the forward evaluation.

Case: 10 speeds 30-140 km/h, rounded flat 0.9 mm x 100 mm, contact ``"3d"`` (parametric
family, ``SimConfig(contact_element=2e-3)``), 1 impact position (0.1 m), misfit
mean(((model - data) / 2e5)^2) with data the model at theta * 1.02. Rows: the forward
evaluation (loss only), plain reverse mode (``jax.value_and_grad`` through ``run_scan``), the
adjoint (``max_force_model(..., adjoint=True)``, ``jax.value_and_grad``) and forward mode
(``jax.jacfwd``, 2 parameters). Compiled first; then each gradient in its own block of
``--repeats`` rounds (after one warm-up round), every round timing the forward and then the
gradient (the machine is shared: a paired ratio per round, their median reported), best and
median wall times and the best process CPU time (all threads; less sensitive to other load)
reported with the load average.

``--memory``: peak RSS of each gradient in a fresh process (``ru_maxrss``, compilation
included; the "forward" row is the floor of a process that builds the model).

Run: ``python benchmarks/bench_gradient.py [--contact 3d] [--element 2e-3] [--repeats 5]
[--memory]``. Prints Markdown.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time

SETUP = """
import dataclasses, time
import jax, jax.numpy as jnp, numpy as np
import wfjax as wf
from wfjax import fit
config = dataclasses.replace(wf.SimConfig(), contact_element={element})
speeds = np.linspace(30.0, 140.0, 10) / 3.6
init = wf.Flat.rounded(0.9e-3, 0.1)
par = fit.parametrisation_for(init)
theta = jnp.asarray(par.from_flat(init))
ref = dataclasses.replace(init, extent_bound=par.extent_bound)
plain = fit.max_force_model(speeds, ref, {contact!r}, impact_positions=[0.1], config=config)
adjoint = fit.max_force_model(speeds, ref, {contact!r}, impact_positions=[0.1], config=config,
                              adjoint=True)
data = jnp.asarray(np.asarray(plain(par.to_flat(theta * 1.02))))
def misfit(model):
    return lambda th: jnp.mean(((model(par.to_flat(th)) - data) / 2e5) ** 2)
ROWS = {{
    "forward (loss only)": jax.jit(misfit(plain)),
    "reverse, plain autodiff (value_and_grad)": jax.jit(jax.value_and_grad(misfit(plain))),
    "reverse, adjoint (value_and_grad, adjoint=True)":
        jax.jit(jax.value_and_grad(misfit(adjoint))),
    "forward mode (jacfwd, 2 parameters)": jax.jit(jax.jacfwd(misfit(plain))),
}}
"""


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def _timed(fn, theta) -> tuple[float, float]:
    """(wall [s], process CPU [s]) of one call of ``fn(theta)``."""
    import jax

    c0, t0 = time.process_time(), time.perf_counter()
    jax.block_until_ready(fn(theta))
    return time.perf_counter() - t0, time.process_time() - c0


def bench_time(contact: str, element: float, repeats: int) -> None:
    scope: dict = {}
    t0 = time.perf_counter()
    exec(SETUP.format(contact=contact, element=element), scope)  # noqa: S102
    print(f"setup (family from the cache or built) {time.perf_counter() - t0:.1f} s")
    import jax

    rows, theta = scope["ROWS"], scope["theta"]
    fwd = "forward (loss only)"
    compile_s = {}
    for name, fn in rows.items():
        t0 = time.perf_counter()
        jax.block_until_ready(fn(theta))
        compile_s[name] = time.perf_counter() - t0
    print(f"load average before timing: {_load()}")
    # Each gradient in its own block of rounds, every round the forward then the gradient
    # (a paired ratio), as a fit calls one gradient back to back: interleaving the rows
    # made the adjoint 1.3x slower after the plain reverse mode's large arrays (measured).
    times = {k: [] for k in rows}
    cpu = {k: [] for k in rows}
    pair_ratio = {k: [] for k in rows}
    for name, fn in rows.items():
        if name == fwd:
            continue
        _timed(rows[fwd], theta), _timed(fn, theta)  # one unrecorded round: the block's warm-up
        for _ in range(repeats):
            (wf, cf), (wg, cg) = _timed(rows[fwd], theta), _timed(fn, theta)
            times[fwd].append(wf), cpu[fwd].append(cf)
            times[name].append(wg), cpu[name].append(cg)
            pair_ratio[name].append(wg / wf)
    print(f"load average after timing: {_load()}\n")
    base, base_cpu = min(times[fwd]), min(cpu[fwd])
    print("| evaluation | first call [s] | best [s] | median [s] | best / forward | "
          "median of paired ratios | CPU best [s] | CPU / forward |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for name, t in times.items():
        paired = f"{statistics.median(pair_ratio[name]):.2f}" if pair_ratio[name] else "1.00"
        print(f"| {name} | {compile_s[name]:.1f} | {min(t):.3f} | {statistics.median(t):.3f} "
              f"| {min(t) / base:.2f} | {paired} "
              f"| {min(cpu[name]):.3f} | {min(cpu[name]) / base_cpu:.2f} |")
    plain, adj = rows["reverse, plain autodiff (value_and_grad)"], rows[
        "reverse, adjoint (value_and_grad, adjoint=True)"]
    (v1, g1), (v2, g2) = plain(theta), adj(theta)
    print(f"\nloss plain {float(v1)!r}, adjoint {float(v2)!r}; gradient plain {g1}, "
          f"adjoint {g2}")


MEMORY_BODY = """
import resource
fn = ROWS[{row!r}]
jax.block_until_ready(fn(theta))
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
"""


def bench_memory(contact: str, element: float) -> None:
    print("| evaluation (fresh process) | peak RSS [MiB] |")
    print("| --- | ---: |")
    for row in ("forward (loss only)", "reverse, plain autodiff (value_and_grad)",
                "reverse, adjoint (value_and_grad, adjoint=True)",
                "forward mode (jacfwd, 2 parameters)"):
        code = SETUP.format(contact=contact, element=element) + MEMORY_BODY.format(row=row)
        env = dict(os.environ, JAX_PLATFORMS="cpu")
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                             text=True, check=False)
        if out.returncode != 0:
            raise RuntimeError(out.stderr[-2000:])
        print(f"| {row} | {float(out.stdout.split()[-1]):.0f} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--contact", default="3d")
    ap.add_argument("--element", type=float, default=2e-3)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--memory", action="store_true", help="peak RSS in fresh processes")
    args = ap.parse_args()
    if args.memory:
        bench_memory(args.contact, args.element)
    else:
        bench_time(args.contact, args.element, args.repeats)


if __name__ == "__main__":
    main()

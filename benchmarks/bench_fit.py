"""Benchmark of wfjax.fit: gradient vs forward cost of a 10-speed max-force misfit, and the
full fit of the notebook case (notebooks/fit_flat.ipynb, 8 speeds x 3 impact positions).

Run: python benchmarks/bench_fit.py [--skip-fit]. Compile time is reported apart from run
time (best of 3 runs after the first call).
"""

from __future__ import annotations

import argparse
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

import wfjax as wf
from wfjax import fit


def _timed(fn, *args, repeat=3):
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t0
    runs = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        runs.append(time.perf_counter() - t0)
    best = min(runs)
    return first - best, best


def bench_gradient():
    speeds = np.linspace(30.0, 140.0, 10) / 3.6
    par = fit.RoundedFlatParam(extent_bound=0.075)
    theta = jnp.asarray(par.from_flat(wf.Flat.rounded(0.9e-3, 0.1)))
    ref = jax.tree_util.tree_map(np.asarray, par.to_flat(theta))
    model = fit.max_force_model(speeds, ref, "hertz-trajectory", impact_positions=[0.1])
    data = jnp.asarray(np.asarray(model(par.to_flat(theta + 0.1))))

    def residuals(th):
        return (model(par.to_flat(th)) - data) / 2e5

    def loss(th):
        return jnp.mean(residuals(th) ** 2)

    def forward_grad(th):  # what fit_flat uses for <= 4 parameters (and gives Gauss-Newton's J)
        J, r = jax.jacfwd(lambda t: (residuals(t),) * 2, has_aux=True)(th)
        return jnp.mean(r**2), 2 * J.T @ r / r.size

    rows = {}
    for name, fn in (("forward (loss only)", jax.jit(loss)),
                     ("gradient, forward mode (jacfwd, 2 params)", jax.jit(forward_grad)),
                     ("gradient, reverse mode (jax.grad)", jax.jit(jax.value_and_grad(loss)))):
        rows[name] = _timed(fn, theta)
    base = rows["forward (loss only)"][1]
    print(f"10-speed max-force misfit, hertz-trajectory, 1 impact position, "
          f"{model.info['n_steps']} steps per run")
    print(f"{'':45s} {'compile [s]':>12s} {'run [s]':>9s} {'ratio':>7s}")
    for name, (c, r) in rows.items():
        print(f"{name:45s} {c:12.2f} {r:9.3f} {r / base:7.2f}")


def bench_notebook_fit():
    speeds_kmh = np.linspace(40.0, 140.0, 8)
    speeds = speeds_kmh / 3.6
    truth = wf.Flat.rounded(0.9e-3, 0.100)
    initial = wf.Flat.rounded(1.35e-3, 0.150)
    param = fit.parametrisation_for(initial)
    truth_b = wf.Flat("rounded", truth.depth, truth.length, extent_bound=param.extent_bound)
    model = fit.max_force_model(speeds, truth_b, impact_positions=3)
    clean = np.asarray(model(truth_b))
    measured = clean * (1 + 0.03 * np.random.default_rng(7).standard_normal(clean.size))
    t0 = time.perf_counter()
    res = fit.fit_flat(fit.MaxForceData(speeds, measured), initial, impact_positions=3,
                       parametrisation=param)
    wall = time.perf_counter() - t0
    err = {n: 100 * (res.params[n] / getattr(truth, n) - 1) for n in ("depth", "length")}
    print(f"notebook case fit (8 speeds x 3 positions, LBFGS): {wall:.1f} s incl. compile, "
          f"{res.n_iterations} iterations, {res.message}")
    print(f"  depth error {err['depth']:+.2f} %, length error {err['length']:+.2f} %")


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--skip-fit", action="store_true", help="only the gradient benchmark")
    args = parser.parse_args()
    print(f"{platform.machine()}, {jax.devices()[0].platform}, jax {jax.__version__}")
    bench_gradient()
    if not args.skip_fit:
        bench_notebook_fit()


if __name__ == "__main__":
    main()

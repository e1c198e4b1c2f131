"""Peak memory of each expensive step, each in its own fresh process.

A process's peak resident set size (``ru_maxrss``) only grows, so measuring several steps in
one process hides all but the largest. Here every step runs in a new Python process (one CPU
device, float64) and reports its own peak and wall time (compilation included); the "import
only" row is the floor every other row includes. "cold" rows use a fresh cache directory;
the others share one that holds the track modal model and the new flat's 3D table, and
every row leaves its own results there for the rows below (the table built in one row is
loaded by the next).

Run: ``python benchmarks/bench_memory.py``. Prints Markdown.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile

from _tracks import RECORDED  # benchmarks/, the script's folder

PRELUDE = f"""
RECORDED = {RECORDED!r}
import resource, time
import jax, jax.numpy as jnp, numpy as np
import wfjax as wf
from wfjax.loop.structure import structure
from wfjax.model.vehicle import Vehicle
t0 = time.perf_counter()
"""

REPORT = """
jax.effects_barrier()
print(time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
"""

STRUCTURE = ("structure(Vehicle.single(), [wf.Wheel()], wf.Track(**RECORDED), "
             "wf.SimConfig())")


def _table(flat: str) -> str:
    return (f"jax.block_until_ready(wf.contact.laws.prepare('3d', {flat}, wf.Wheel(), "
            "wf.Track(**RECORDED), wf.Material(), wf.SimConfig()))")


def _misfit(checkpoint: bool, evaluate: str) -> str:
    """Max force of 10 speeds (hertz-trajectory) and ``evaluate`` of its squared sum."""
    return f"""
from wfjax import fit
speeds = np.linspace(30.0, 140.0, 10) / 3.6
par = fit.RoundedFlatParam(extent_bound=0.075)
theta = jnp.asarray(par.from_flat(wf.Flat.rounded(0.9e-3, 0.1)))
ref = jax.tree_util.tree_map(np.asarray, par.to_flat(theta))
model = fit.max_force_model(speeds, ref, "hertz-trajectory", impact_positions=[0.1],
                            checkpoint={checkpoint})
def loss(th):
    return jnp.sum(model(par.to_flat(th)) ** 2)
jax.block_until_ready(jax.jit({evaluate})(theta))
"""


ROUNDED = "wf.Flat.rounded(0.9e-3, 0.1)"
SETUP = f"{STRUCTURE}; {_table('wf.Flat.new(0.9e-3)')}"
STEPS = {
    "import only": ("cold", "pass"),
    "track modal model, cold build (8 el./bay, <= 10 kHz kept)": ("cold", STRUCTURE),
    "track modal model, load from the disk cache": ("warm", STRUCTURE),
    "3D contact table build (rounded 0.9 mm / 100 mm, R_R = 0.30 m)": ("warm", _table(ROUNDED)),
    "simulate, 3D table, 100 km/h (table cached)": (
        "warm", f"wf.simulate({ROUNDED}, 100 / 3.6, contact='3d')"),
    "default sweep, 580 runs, 3D (tables cached)": (
        "warm", f"wf.sweep([{ROUNDED}, wf.Flat.new(0.9e-3)], "
                "np.arange(20.0, 301.0, 10.0) / 3.6, 10, progress=False)"),
    "forward: max force of 10 speeds, hertz-trajectory": ("warm", _misfit(False, "loss")),
    "reverse-mode gradient of the same (jax.grad)": ("warm", _misfit(False, "jax.grad(loss)")),
    "reverse-mode gradient, checkpoint=True": ("warm", _misfit(True, "jax.grad(loss)")),
}


def run_step(body: str, cache_dir: str) -> tuple[float, float]:
    """(wall [s], peak RSS [MiB]) of ``body`` in a fresh process."""
    env = dict(os.environ, WFJAX_CACHE_DIR=cache_dir, JAX_PLATFORMS="cpu",
               XLA_FLAGS="--xla_force_host_platform_device_count=1")
    code = PRELUDE + body + "\n" + REPORT
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=False)
    if out.returncode != 0:
        raise RuntimeError(out.stderr[-2000:])
    wall, rss = out.stdout.split()[-2:]
    return float(wall), float(rss)


def main() -> None:
    warm = tempfile.mkdtemp(prefix="wfjax_mem_warm_")
    run_step(SETUP, warm)  # modal model and the new flat's table for the "warm" rows
    print("| step | wall [s] | peak RSS [MiB] |")
    print("| --- | --- | --- |")
    for name, (cache, body) in STEPS.items():
        cache_dir = tempfile.mkdtemp(prefix="wfjax_mem_cold_") if cache == "cold" else warm
        wall, rss = run_step(body, cache_dir)
        print(f"| {name} | {wall:.1f} | {rss:.0f} |", flush=True)


if __name__ == "__main__":
    main()

"""Simulation benchmark: time steps per second of each contact model and the 3D direct mode.

Rounded flat d = 0.9 mm, l = 100 mm, 100 km/h, impact above a sleeper, default ``SimConfig``
(1 mm of travel per step). The prepared contact law (tables, node sets) and the modal models
are built once and timed apart; the time loop (:func:`wfjax.loop.run.run_scan`; the 3D
direct mode is :class:`wfjax.contact.direct3d.Direct3DLaw`, with every solve on its window
and, for comparison, on the table's whole grid) is timed with
``block_until_ready``:
compile time from ``jax.monitoring`` compile events, run time the median of repeats (the
direct mode: its first call minus compilation, one repeat). Peak memory is the process's
``ru_maxrss`` after each model (monotone: a model's own peak is at most that).

``--loop N``: instead, ``wf.simulate`` called in one process at N speeds (new 0.9 mm flat,
Hertz-trajectory, 40 km/h up in steps of 8 km/h; each speed a program of its own step count):
the wall time of each call and the process's memory maps (``/proc/self/maps``) after it.

Run: ``python benchmarks/bench_simulate.py [--no-direct] [--repeats 3] [--loop 20]``. Prints
Markdown.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import time

import jax
from _tracks import RECORDED  # benchmarks/, the script's folder

import wfjax as wf
from wfjax._compile_clock import compile_seconds
from wfjax.contact import laws
from wfjax.loop.run import run_scan
from wfjax.loop.structure import structure
from wfjax.model.vehicle import Vehicle
from wfjax.scenario.windows import n_steps_for, simulation_window


def timed(fn):
    """(wall [s], compile [s]) of ``fn()`` with its outputs blocked on."""
    c0 = compile_seconds()
    t0 = time.perf_counter()
    jax.block_until_ready(fn())
    return time.perf_counter() - t0, compile_seconds() - c0


def peak_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def simulate_loop(n: int) -> None:
    """``wf.simulate`` at ``n`` speeds in this process: seconds and memory maps per call."""
    def maps() -> int:
        with open("/proc/self/maps") as f:
            return sum(1 for _ in f)

    print(f"memory maps at the start: {maps()}\n\n| speed [km/h] | call [s] | memory maps |")
    print("| --- | --- | --- |")
    for k in range(n):
        v = 40.0 + 8.0 * k
        t0 = time.perf_counter()
        wf.simulate(wf.Flat.new(0.9e-3), v / 3.6, contact="hertz-trajectory")
        print(f"| {v:.0f} | {time.perf_counter() - t0:.2f} | {maps()} |", flush=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--no-direct", action="store_true", help="skip the 3D per-step direct mode")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--loop", type=int, default=0, help="wf.simulate at this many speeds")
    a = p.parse_args()
    if a.loop:
        return simulate_loop(a.loop)
    flat = wf.Flat.rounded(depth=0.9e-3, length=0.1)
    wheel, track, material, config = wf.Wheel(), wf.Track(**RECORDED), wf.Material(), wf.SimConfig()
    v, imp = 100 / 3.6, 0.0
    n, dt = n_steps_for(flat, v, config)
    s0, s1 = simulation_window(flat, v, config)
    travel = s1 - s0
    t_struct, _ = timed(lambda: structure(Vehicle.single(), [wheel], track, config))
    struct = structure(Vehicle.single(), [wheel], track, config)
    print(f"devices {jax.devices()}, x64 {jax.config.jax_enable_x64}; {n} steps, dt = "
          f"{dt * 1e6:.1f} us, {travel:.3f} m of travel at 100 km/h; modal models "
          f"{t_struct:.2f} s (from the disk cache if warm)\n")
    print("| contact | prepare law [s] | compile [s] | run [s] | steps/s | run per 1 m travel [s] "
          "| max force [kN] | peak RSS [MiB] |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for contact in ("3d", "2d", "hertz-trajectory", "hertz-profile"):
        t0 = time.perf_counter()
        law = laws.prepare(contact, flat, wheel, track, material, config)
        jax.block_until_ready(law)
        t_prep = time.perf_counter() - t0

        def run(law=law):
            return run_scan(law, struct, v, dt, imp + s0, imp, n, config.newton_iterations)

        first, comp = timed(run)
        t_run = statistics.median(timed(run)[0] for _ in range(a.repeats))
        fmax = float(run()["force"].max())
        print(f"| {contact} (table)" if contact == "3d" else f"| {contact}", end="")
        print(f" | {t_prep:.2f} | {comp:.2f} | {t_run:.3f} | {n / t_run:.3g} | "
              f"{t_run / travel:.3f} | {fmax / 1e3:.1f} | {peak_mib():.0f} |")
    if not a.no_direct:
        cfg = wf.SimConfig(contact_mode_3d="direct")
        direct_law = laws.prepare("3d", flat, wheel, track, material, cfg)
        for name, law in (("windows", direct_law), ("whole grid", direct_law.on_whole_grid())):
            out = {}

            def direct(law=law, out=out):
                out["h"] = run_scan(law, struct, v, dt, imp + s0, imp, n,
                                      cfg.newton_iterations)
                return out["h"]

            first, comp = timed(direct)
            t_run = first - comp
            print(f"| 3d (direct, per step, {name}) | - | {comp:.2f} | {t_run:.2f} | "
                  f"{n / t_run:.3g} | {t_run / travel:.2f} | "
                  f"{float(out['h']['force'].max()) / 1e3:.1f} | {peak_mib():.0f} |")

if __name__ == "__main__":
    main()

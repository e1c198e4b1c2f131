"""Baseline: the Hertz-trajectory sweep written the way a user without wfjax would.

NumPy/SciPy, a Python time loop, ``scipy.optimize.brentq`` for the contact equation of every
step, and the same wheel and track modal data (taken from :func:`wfjax.model.track.modal_model` and
:func:`wfjax.model.wheel.modal_model` as NumPy arrays), the same mode shapes at the contact
positions, the same wheel-centre trajectory, time step and step count as :func:`wfjax.sweep`.
The script runs both on the same case and prints the largest relative difference of the
maximum and minimum forces and the speed ratio (wfjax compiled; compile time apart).

Run: ``python benchmarks/bench_baseline.py [--speeds-kmh 40,80,120,160] [--positions 3]
[--host-devices N]``. wfjax runs on N CPU devices (default: one per core, as the ``wfjax``
command does; ``--host-devices 1`` for one), the baseline on one core as NumPy does.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import jax
import numpy as np
import scipy.optimize
from _tracks import RECORDED  # benchmarks/, the script's folder

import wfjax as wf
from wfjax.contact import laws
from wfjax.model import track as T
from wfjax.model import wheel as W
from wfjax.scenario.windows import run_windows


def step_coefficients(poles: np.ndarray, dt: float):
    """First-order-hold update of q' = lambda q + u: (e^z, a_prev, a_now), z = lambda dt."""
    z = poles * dt
    e = np.exp(z)
    return e, dt * (e * (z - 1.0) + 1.0) / z**2, dt * (e - 1.0 - z) / z**2


def simulate_numpy(c_h, s_grid, drop, poles_r, weights, phi, res, poles_w, residues_w, preload,
                   speed, dt, x_start, impact, n_steps):
    """One Hertz-trajectory simulation; returns force [n_steps] [N].

    phi: complex [n_steps, n_modes] rail mode shapes at the contact positions; res: [n_steps]
    residual compliance [m/N]; other arguments as in :func:`wfjax.loop.run.time_loop`.
    """
    def law(delta, s):
        comp = delta - np.interp(s, s_grid, drop, left=0.0, right=0.0)
        return c_h * comp**1.5 if comp > 0 else 0.0

    e_r, ap_r, an_r = step_coefficients(poles_r, dt)
    e_w, ap_w, an_w = step_coefficients(poles_w, dt)
    c_wheel = float(np.real(np.sum(residues_w * an_w)))
    q = -phi[0] * preload / poles_r
    xi_r0 = float(np.real(np.sum(weights * phi[0] * q))) + res[0] * preload
    s0 = x_start - impact
    delta0 = scipy.optimize.brentq(lambda d: law(d, s0) - preload, 0.0, 1e-3, xtol=1e-16)
    xi_w_ref = xi_r0 + delta0
    p = np.zeros_like(poles_w)
    force = np.empty(n_steps)
    force[0] = f_prev = preload
    for n in range(1, n_steps):
        s = x_start + speed * dt * n - impact
        q_hat = e_r * q + ap_r * phi[n - 1] * f_prev
        xi_r_free = float(np.real(np.sum(weights * phi[n] * q_hat)))
        c = float(np.real(np.sum(weights * an_r * phi[n] * phi[n]))) + res[n] + c_wheel
        p_hat = e_w * p + ap_w * (f_prev - preload)
        xi_w_free = xi_w_ref - float(np.real(np.sum(residues_w * p_hat))) + c_wheel * preload
        d_free = xi_w_free - xi_r_free
        f_free = law(d_free, s)
        if f_free <= 0.0:
            f = 0.0
        else:
            delta = scipy.optimize.brentq(lambda d, s=s, d0=d_free, c=c: d - d0 + c * law(d, s),
                                          d_free - c * f_free - 1e-12, d_free, xtol=1e-16)
            f = law(delta, s)
        q = q_hat + an_r * phi[n] * f
        p = p_hat + an_w * (f - preload)
        force[n] = f_prev = f
    return force


def baseline_sweep(flat, speeds, positions, track):
    """(max force, min force) [n_speeds, n_positions] [N] with the NumPy/SciPy loop on
    ``track``."""
    wheel, material = wf.Wheel(), wf.Material()
    config = wf.SimConfig().resolved()
    model = T.modal_model(track, max_frequency=config.track_max_frequency)
    wm = W.modal_model(wheel)
    law = laws.prepare("hertz-trajectory", flat, wheel, track, material, config)
    c_h, s_grid, drop = (np.asarray(a) for a in (law.c_h, law.s_grid, law.drop))
    poles_r, weights = np.asarray(model.poles), np.asarray(model.weights)
    poles_w, residues_w = np.asarray(wm.poles), np.asarray(wm.residues)
    steps, dts, starts, run_ins = run_windows(flat, speeds, config)  # as wfjax.sweep
    fmax = np.zeros((speeds.size, positions.size))
    fmin = np.zeros_like(fmax)
    for i, v in enumerate(speeds):
        n_steps, dt, s_start, run_in = int(steps[i]), dts[i], starts[i], int(run_ins[i])
        for j, pos in enumerate(positions):
            x = pos + s_start + v * dt * np.arange(n_steps)
            phi = np.asarray(T.mode_shapes_at(model, x))  # the FE shape functions, as data
            res = np.asarray(T.residual_compliance_at(model, x))
            f = simulate_numpy(float(c_h), s_grid, drop, poles_r, weights, phi, res, poles_w,
                               residues_w, float(wheel.preload), float(v), dt, pos + s_start,
                               float(pos), n_steps)
            fmax[i, j], fmin[i, j] = f[run_in:].max(), f[run_in:].min()
    return fmax, fmin


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--speeds-kmh", default="40,80,120,160")
    p.add_argument("--positions", type=int, default=3)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--host-devices", type=int, default=os.cpu_count() or 1)
    a = p.parse_args()
    os.environ["XLA_FLAGS"] = (f"{os.environ.get('XLA_FLAGS', '')} "
                               f"--xla_force_host_platform_device_count={a.host_devices}")
    flat = wf.Flat.rounded(depth=0.9e-3, length=0.1)
    speeds = np.array([float(s) for s in a.speeds_kmh.split(",")]) / 3.6
    from wfjax.sweeps import impact_positions_grid

    positions = impact_positions_grid(a.positions)
    n_runs = speeds.size * positions.size

    track = wf.Track(**RECORDED)  # both loops on one track (Track() would be lengthened)
    T.modal_model(track)  # warm the disk cache for both
    t0 = time.perf_counter()
    ref = wf.sweep(flat, speeds, positions, contact="hertz-trajectory", track=track,
                   progress=False)
    t_first = time.perf_counter() - t0
    runs = []
    for _ in range(a.repeats):
        t0 = time.perf_counter()
        ref = wf.sweep(flat, speeds, positions, contact="hertz-trajectory", track=track,
                       progress=False)
        runs.append(time.perf_counter() - t0)
    t_wf = statistics.median(runs)

    t0 = time.perf_counter()
    fmax, fmin = baseline_sweep(flat, speeds, positions, track)
    t_np = time.perf_counter() - t0

    run_steps = int(run_windows(flat, speeds, wf.SimConfig())[0].sum()) * positions.size
    d_max = np.max(np.abs(fmax - ref.max_force[0]) / ref.max_force[0])
    d_min = np.max(np.abs(fmin - ref.min_force[0]) / ref.max_force[0])
    print(f"Hertz-trajectory sweep, rounded 0.9 mm/100 mm flat, {speeds.size} speeds x "
          f"{positions.size} positions = {n_runs} runs, {run_steps} steps in all; wfjax on "
          f"{len(jax.devices())} {jax.devices()[0].platform} device(s)\n")
    print("| implementation | wall [s] | per run [ms] | steps/s |")
    print("| --- | --- | --- | --- |")
    print(f"| NumPy/SciPy baseline (Python loop, brentq) | {t_np:.2f} | {1e3 * t_np / n_runs:.0f}"
          f" | {run_steps / t_np:.3g} |")
    print(f"| wfjax.sweep, compiled (median of {a.repeats}) | {t_wf:.3f} | "
          f"{1e3 * t_wf / n_runs:.1f} | {run_steps / t_wf:.3g} |")
    print(f"| wfjax.sweep, first call (incl. compilation) | {t_first:.2f} | "
          f"{1e3 * t_first / n_runs:.0f} | {run_steps / t_first:.3g} |")
    print(f"\nspeed ratio baseline / wfjax: {t_np / t_wf:.0f}x compiled, {t_np / t_first:.1f}x "
          f"including compilation")
    print(f"agreement: max |dF_max| / F_max = {d_max:.2e}, max |dF_min| / F_max = {d_min:.2e}")


if __name__ == "__main__":
    main()

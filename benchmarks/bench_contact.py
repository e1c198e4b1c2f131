"""Benchmark: 3D contact solver (wfjax.contact.kalker) vs Tamaas' PolonskyKeerRey, and tables.

Run: python benchmarks/bench_contact.py [--quick]

1. Cold solves of a smooth wheel (R_W = R_R = 0.45 m, 118 kN, force-controlled) on n x n grids
   covering 24 mm x 24 mm, n = 32 ... 256. wfjax: zero-padded FFT (2n x 2n). Tamaas: periodic,
   so its domain is padded to 2n x 2n with the same element size (its influence is the
   spectral point-load operator, not Love's rectangles, so forces/approaches differ by O(h^2)).
   Same tolerance (1e-8; wfjax: CG relative residual, Tamaas: its complementarity error).
2. A sequence of 20 neighbouring flat positions (rounded flat d = 0.9 mm, l = 100 mm, s steps
   of 0.5 mm through the flat's edge), force-controlled at 118 kN: wfjax warm-started from the
   previous pressure inside ``lax.scan``; Tamaas re-solving each position (a fresh solver per
   position, its pressure initial guess is its own).
3. The reference case of CONTACT (issue 20): a rounded flat at 0.25 mm elements, ten
   positions, each on the grid cropped to its overlap; plain vs preconditioned CG and Tamaas.
4. Table build time for the flats in use, each solve on the window around its rigid overlap
   (the default) and on the table's whole grid, in the same run (times include compilation).
5. The default sweep's two tables (rounded 0.9 mm x 100 mm and new 0.9 mm, R_R = 0.30 m, 1 mm)
   from an empty cache in a fresh process, as ``wfjax sweep`` builds them
   (``table_law.cached_tables_3d``): wall and CPU time, compilation included (``--cold-only``
   runs just this, ``--repeat N`` N fresh processes).

Compile time is excluded (reported separately); times are medians of repeats, after
``block_until_ready``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import wfjax as wf
from wfjax.contact import geometry3d, kalker, table_spec, tables

MAT = wf.Material()
R = 0.45
F = 118e3
TOL = 1e-8
HALF = 12e-3


def _median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def grid(n, half=HALF, half_x=None):
    h = 2 * half / n
    x = (np.arange(n) - (n - 1) / 2) * h if half_x is None else (
        np.arange(int(round(2 * half_x / h))) - (int(round(2 * half_x / h)) - 1) / 2) * h
    y = (np.arange(n) - (n - 1) / 2) * h
    return x, y, h


def wfjax_cold(n, repeats):
    x, y, h = grid(n)
    g = geometry3d.gap_3d(wf.Flat.none(), 0.0, x, y, R, R)
    f = jax.jit(lambda g: kalker.solve(g, h, h, MAT, force=F, tol=TOL, stiffness=False,
                                       validate=False))
    t0 = time.perf_counter()
    r = jax.block_until_ready(f(g))
    compile_t = time.perf_counter() - t0
    return _median_time(lambda: f(g), repeats), compile_t, float(r.approach), r


def tamaas_model(nx, ny, h):
    import tamaas as tm

    model = tm.ModelFactory.createModel(tm.model_type.basic_2d, [2 * nx * h, 2 * ny * h],
                                        [2 * nx, 2 * ny])
    model.E = MAT.youngs_modulus / 2  # tamaas: E* = E / (1 - nu^2); two bodies -> E/2
    model.nu = MAT.poisson_ratio
    return model


def tamaas_solve(gap, h):
    import tamaas as tm

    nx, ny = gap.shape
    model = tamaas_model(nx, ny, h)
    surface = np.full((2 * nx, 2 * ny), -np.max(gap) * 4)  # far below: never in contact
    surface[:nx, :ny] = -np.asarray(gap)
    solver = tm.PolonskyKeerRey(model, surface, TOL)
    solver.max_iter = 10000
    mean_p = F / (4 * nx * ny * h * h)
    t0 = time.perf_counter()
    solver.solve(mean_p)
    dt = time.perf_counter() - t0
    return dt, model


def tamaas_cold(n, repeats):
    import tamaas as tm

    tm.set_log_level(tm.LogLevel.error)
    x, y, h = grid(n)
    g = np.asarray(geometry3d.gap_3d(wf.Flat.none(), 0.0, x, y, R, R))
    times = [tamaas_solve(g, h)[0] for _ in range(repeats)]
    _, model = tamaas_solve(g, h)
    p = np.asarray(model.traction).reshape(2 * n, 2 * n)
    return statistics.median(times), float(p.max())


def sequence(n, steps=20):
    flat = wf.Flat.rounded(0.9e-3, 0.1)
    x, y, h = grid(n)
    s_values = jnp.asarray(-0.058 + 0.5e-3 * np.arange(steps))

    def gap(s):
        return geometry3d.gap_3d(flat, s, x, y, R, R)

    @jax.jit
    def warm(s_values):
        def step(p, s):
            r = kalker.solve(gap(s), h, h, MAT, force=F, p_init=p, tol=TOL, stiffness=False,
                             validate=False)
            return r.pressure, (r.approach, r.diagnostics.cg_iterations)

        return jax.lax.scan(step, jnp.zeros((len(x), len(y))), s_values)[1]

    @jax.jit
    def cold(s_values):
        def step(p, s):
            r = kalker.solve(gap(s), h, h, MAT, force=F, tol=TOL, stiffness=False,
                             validate=False)
            return p, (r.approach, r.diagnostics.cg_iterations)

        return jax.lax.scan(step, jnp.zeros((len(x), len(y))), s_values)[1]

    jax.block_until_ready(warm(s_values))
    jax.block_until_ready(cold(s_values))
    t_warm = _median_time(lambda: warm(s_values), 3) / steps
    t_cold = _median_time(lambda: cold(s_values), 3) / steps
    (d_w, it_w), (d_c, it_c) = warm(s_values), cold(s_values)
    assert np.allclose(d_w, d_c, rtol=1e-6)
    t_tm = 0.0
    for s in np.asarray(s_values):
        t_tm += tamaas_solve(np.asarray(gap(s)), h)[0]
    return dict(n=n, wfjax_warm_ms=t_warm * 1e3, wfjax_cold_ms=t_cold * 1e3,
                tamaas_ms=t_tm / steps * 1e3, cg_warm=float(np.mean(it_w)),
                cg_cold=float(np.mean(it_c)))


def contact_case(quick):
    """The reference case of the field's program CONTACT (issue 20): rounded flat 0.9 mm x
    100 mm, R_W = 0.45 m, R_R = 0.30 m, 0.25 mm elements, 118 kN, ten flat positions s = -60
    ... 0 mm, each solved cold on the grid cropped to its rigid overlap at 0.15 mm (+2
    elements): wfjax with plain and with preconditioned CG, and Tamaas on the same grids."""
    flat = wf.Flat.rounded(0.9e-3, 0.1)
    h, rr = 0.25e-3, 0.30
    x_all, y_all = np.arange(-400, 401) * h, np.arange(-120, 121) * h
    rows = []
    for s in np.linspace(-0.06, 0.0, 4 if quick else 10):
        g = np.asarray(geometry3d.gap_3d(flat, s, x_all, y_all, R, rr))
        inside = g - g.min() < 0.15e-3
        ii, jj = np.nonzero(inside.any(1))[0], np.nonzero(inside.any(0))[0]
        g = jnp.asarray(g[ii[0] - 2:ii[-1] + 3, jj[0] - 2:jj[-1] + 3])
        nx, ny = g.shape
        row = dict(s_mm=float(s) * 1e3, nx=nx, ny=ny)
        for precondition in (False, True):
            cfg = kalker._Config(nx, ny, h, h, "fft", TOL, 1000, precondition)
            f = jax.jit(lambda g, cfg=cfg: kalker._solve_impl(cfg, g, MAT, None, F, None, 50,
                                                              False, True)[0])
            r = jax.block_until_ready(f(g))
            name = "pcg" if precondition else "cg"
            row[f"{name}_ms"] = _median_time(lambda f=f, g=g: f(g), 3) * 1e3
            row[f"{name}_iterations"] = int(r.diagnostics.cg_iterations)
            row[f"{name}_outer"] = int(r.diagnostics.iterations)
            row[f"{name}_approach_um"] = float(r.approach) * 1e6
        row["contact_elements"] = int(r.contact.sum())
        try:
            row["tamaas_ms"] = tamaas_solve(np.asarray(g), h)[0] * 1e3
        except ImportError:
            row["tamaas_ms"] = float("nan")
        rows.append(row)
        print(row, flush=True)
    n_el = sum(r["nx"] * r["ny"] for r in rows)
    summary = dict(elements_mean=n_el / len(rows),
                   cg_ms_mean=statistics.mean(r["cg_ms"] for r in rows),
                   pcg_ms_mean=statistics.mean(r["pcg_ms"] for r in rows),
                   tamaas_ms_mean=statistics.mean(r["tamaas_ms"] for r in rows),
                   pcg_us_per_element=sum(r["pcg_ms"] for r in rows) * 1e3 / n_el,
                   contact_program_us_per_element=60e3 / 7800)
    print(summary, flush=True)
    return dict(rows=rows, summary=summary)


def table_builds(quick):
    cases = [("rounded d=0.9 l=100, R_R=0.45", wf.Flat.rounded(0.9e-3, 0.1), 0.45),
             ("new d=0.9, R_R=0.30", wf.Flat.new(0.9e-3), 0.30)]
    if not quick:
        cases += [("rounded d=2 l=1.76 l0, R_R=0.45", wf.Flat.rounded_relative(2e-3), 0.45),
                  ("rounded d=0.25 l=1.76 l0, R_R=0.30", wf.Flat.rounded_relative(0.25e-3),
                   0.30)]
    out = []
    for name, flat, rr in cases:
        spec = table_spec.table_spec(flat, R, rr, MAT)
        times, built = {}, {}
        for windows in (True, False):  # each solve on its overlap's window / the whole grid
            t0 = time.perf_counter()
            built[windows] = jax.block_until_ready(
                tables.build_table_3d(flat, R, rr, MAT, spec=spec, windows=windows))
            times[windows] = time.perf_counter() - t0
        tab = built[True]
        plan = windows.window_plan(spec, flat, tables._solve_positions(spec),
                                  margin=windows.TABLE_WINDOW_MARGIN)
        out.append(dict(flat=name, seconds=times[True], whole_grid_seconds=times[False],
                        speedup=times[False] / times[True], grid=f"{spec.nx}x{spec.ny}",
                        window_sizes=plan.sizes, n_s=spec.n_s, n_t=spec.n_t,
                        converged=float(tab.converged),
                        max_rel_diff=float(np.max(np.abs(tab.force - built[False].force))
                                           / np.max(built[False].force)),
                        min_force_at_cmax_kN=float(tab.force[:, -1].min()) / 1e3))
        print(out[-1], flush=True)
    return out


_COLD_TABLES = """
import json, resource, sys, tempfile, time
import jax
jax.config.update("jax_enable_x64", True)
import wfjax as wf
from wfjax.contact import table_law
flats = [wf.Flat.rounded(0.9e-3, 0.1), wf.Flat.new(0.9e-3)]
t0, r0 = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF)
tabs = table_law.cached_tables_3d(flats, 0.45, 0.30, wf.Material(), 1e-3, tempfile.mkdtemp())
r1 = resource.getrusage(resource.RUSAGE_SELF)
print(json.dumps(dict(seconds=time.perf_counter() - t0,
                      cpu_seconds=r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime,
                      converged=[float(t.converged) for t in tabs])))
"""


def default_sweep_tables(repeat):
    """The default sweep's two tables from an empty cache, each run in a fresh process."""
    out = []
    for _ in range(repeat):
        load = open("/proc/loadavg").read().split()[0]
        run = subprocess.run([sys.executable, "-c", _COLD_TABLES], capture_output=True,
                             text=True, check=True)
        out.append(dict(json.loads(run.stdout.strip().splitlines()[-1]), load_before=load))
        print(out[-1], flush=True)
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", default=None)
    ap.add_argument("--cold-only", action="store_true")
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    if args.cold_only:
        default_sweep_tables(args.repeat)
        return
    sizes = [32, 64, 128] if args.quick else [32, 64, 128, 256]
    cold = []
    for n in sizes:
        rep = 5 if n <= 128 else 3
        t_wf, t_c, d_wf, r = wfjax_cold(n, rep)
        t_tm, d_tm = tamaas_cold(n, rep)
        row = dict(n=n, wfjax_ms=t_wf * 1e3, compile_s=t_c, tamaas_ms=t_tm * 1e3,
                   ratio=t_tm / t_wf, p0_wfjax_MPa=float(r.pressure.max()) / 1e6,
                   p0_tamaas_MPa=d_tm / 1e6,
                   outer=int(r.diagnostics.iterations), cg=int(r.diagnostics.cg_iterations))
        cold.append(row)
        print(row, flush=True)
    seq = []
    for n in [64, 128]:
        seq.append(sequence(n))
        print(seq[-1], flush=True)
    contact = contact_case(args.quick)
    builds = table_builds(args.quick)
    result = dict(cold=cold, sequence=seq, contact_case=contact, tables=builds,
                  default_sweep_tables=default_sweep_tables(args.repeat))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(result, fh, indent=1)


if __name__ == "__main__":
    main()

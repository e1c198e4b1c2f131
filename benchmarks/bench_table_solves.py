"""Benchmark: the work inside the default sweep's two 3D table builds (issue 20 item 3).

For the rounded flat 0.9 mm x 100 mm and the new flat 0.9 mm (R_W = 0.45 m, R_R = 0.30 m,
1 mm elements), the solves a build runs and the ones it shares with the smooth-wheel column
(``tables.shared_prefix``), then the active-set and CG iterations of every solve (float32 to
``tables.WINDOWED_TOL``, as the builds), with each solve warm-started from the previous
pressure alone or from the first-order prediction p + E* dc z that ``tables._solve_column``
uses (same windows, a solver that also returns its iteration counts), and the wall / CPU
time of a second build in one process (solvers compiled); then the default build against
float64 to 1e-8 (:func:`precision_change`: the float32 solves' effect on the tables).

Run: ``python benchmarks/bench_table_solves.py``. Prints one line per measurement.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

import wfjax as wf
from wfjax.contact import influence, kalker, table_spec, tables, windows

FLATS = [wf.Flat.rounded(0.9e-3, 0.1), wf.Flat.new(0.9e-3)]
MAT = wf.Material()
TOL = tables.WINDOWED_TOL  # the builds' own tolerance, and their precision at it:
DTYPE = np.float32


def counting_solver(size, h):
    """The window solver of ``tables`` that also returns outer and CG iteration counts."""
    cfg = kalker._Config(size[0], size[1], h, h, "fft", TOL, 1000)

    @jax.jit
    def solve(gpz, approach, material):
        r, z = kalker._solve_impl(cfg, gpz[0], material, approach, None, gpz[1], 50, True,
                                  False, z_init=gpz[2])
        d = r.diagnostics
        return jnp.stack([r.pressure, z]), jnp.stack([
            r.force, r.stiffness, d.converged.astype(float), d.iterations.astype(float),
            d.cg_iterations.astype(float)])

    return solve


def iterations(predict: bool):
    """(outer, CG) iterations over every solve of both tables, no sharing."""
    estar = float(influence.combined_modulus(MAT)) if predict else 0.0
    mat = windows.solver_inputs(MAT, DTYPE)
    outer = cg = 0
    for flat in FLATS:
        spec = table_spec.table_spec(flat, 0.45, 0.30, MAT, 1e-3)
        gaps, onsets = windows.column_gaps(spec, flat, tables._solve_positions(spec))
        boxes = windows.boxes_from_gaps(spec, gaps - gaps.min(axis=(1, 2), keepdims=True),
                              windows.TABLE_WINDOW_MARGIN)
        sizes = tables._grid_sizes(spec, windows.merge_sizes(
            windows.needed_sizes([boxes]), windows.MAX_WINDOW_SIZES, windows.COST_PER_WINDOW_SIZE))
        plan = windows.assign_windows(spec, boxes, sizes)
        solvers = [counting_solver(size, spec.element_size) for size in plan.sizes]
        cs = table_spec.compression_nodes(spec)
        for i in range(len(onsets)):
            gpz = np.zeros((3,) + gaps[i].shape, DTYPE)
            gpz[0] = gaps[i]
            for j, c in enumerate(cs):
                if j:  # estar = 0: the previous pressure alone
                    gpz[1] += estar * (c - cs[j - 1]) * gpz[2]
                k = int(plan.size_index[i, j])
                wx, wy = plan.sizes[k]
                x0, y0 = int(plan.x0[i, j]), int(plan.y0[i, j])
                window = np.s_[:, x0:x0 + wx, y0:y0 + wy]
                pz, out = solvers[k](gpz[window], DTYPE(onsets[i] + c), mat)
                gpz[1:] = 0.0
                gpz[(np.s_[1:],) + window[1:]] = pz
                outer += int(out[3])
                cg += int(out[4])
    return outer, cg


def main():
    total = shared = 0
    for flat in FLATS:
        spec = table_spec.table_spec(flat, 0.45, 0.30, MAT, 1e-3)
        gaps, onsets = windows.column_gaps(spec, flat, tables._solve_positions(spec))
        n = tables.shared_prefix(gaps, onsets, table_spec.compression_nodes(spec))
        total += len(onsets) * (spec.n_t - 1)
        shared += int(n.sum())
    print(f"solves: {total}, shared with the smooth-wheel column: {shared}", flush=True)
    for predict in (False, True):
        outer, cg = iterations(predict)
        start = "p + E* dc z" if predict else "previous p"
        print(f"warm start {start}: {outer} active-set and {cg} CG iterations", flush=True)
    tables.build_tables_3d(FLATS, 0.45, 0.30, MAT, 1e-3)  # compiles the solvers
    t0, c0 = time.perf_counter(), time.process_time()
    tables.build_tables_3d(FLATS, 0.45, 0.30, MAT, 1e-3)
    print(f"second build (solvers compiled): {time.perf_counter() - t0:.2f} s, "
          f"{time.process_time() - c0:.2f} CPU-s", flush=True)
    precision_change()


def precision_change():
    """The default build (float32 to ``tables.WINDOWED_TOL``) against float64 to 1e-8: the
    largest force difference relative to the table's largest force, and the slopes' largest
    (relative to the largest slope), median and 99th-percentile node-wise relative differences,
    per table; then the float64 build's time, as the second build's above."""
    default = tables.build_tables_3d(FLATS, 0.45, 0.30, MAT, 1e-3)
    tables.build_tables_3d(FLATS, 0.45, 0.30, MAT, 1e-3, tol=1e-8)  # compiles the solvers
    t0, c0 = time.perf_counter(), time.process_time()
    tight = tables.build_tables_3d(FLATS, 0.45, 0.30, MAT, 1e-3, tol=1e-8)
    print(f"float64 to 1e-8 (solvers compiled): {time.perf_counter() - t0:.2f} s, "
          f"{time.process_time() - c0:.2f} CPU-s", flush=True)
    for flat, a, b in zip(FLATS, default, tight, strict=True):
        fa, fb = np.asarray(a.force), np.asarray(b.force)
        sa, sb = np.asarray(a.slope), np.asarray(b.slope)
        node = np.abs(sa - sb) / np.maximum(np.abs(sb), np.finfo(float).tiny)
        print(f"{flat.kind}: force {np.abs(fa - fb).max() / np.abs(fb).max():.2g}, slope "
              f"{np.abs(sa - sb).max() / np.abs(sb).max():.2g} (node-wise median "
              f"{np.median(node):.2g}, 99 % {np.quantile(node, 0.99):.2g})", flush=True)


if __name__ == "__main__":
    main()

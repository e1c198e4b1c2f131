"""Contact tables: the 3D contact force F3D(delta, s) tabulated once per flat geometry.

With a smooth straight rail and the quasi-static half-space model, the 3D contact force depends
only on the approach delta and on the wheel position s relative to the position where the flat
centre is at the nominal contact point. A table of it, built once per flat, turns every time
step of every simulation into a cheap interpolation.

Parametrisation (chosen so that every column is smooth and Hertz-like):

* compression c = delta - delta0(s), with delta0(s) the continuum rigid contact onset
  min over x' of gap(x', 0; s) (about -centre_trajectory(s)), found by a fine 1D search. It is
  smooth in s, unlike the minimum over the element centres, which has kinks every time the
  lowest element changes (those made the s-interpolation error ~10x larger near the
  conforming flat centre). The discrete solution has F = 0 for c below the (sub-micron)
  difference to the discrete minimum; F = 0 for c <= 0 exactly.
* the compression axis is tabulated on t = sqrt(c / c_max), uniform in t: a Hertz column
  F = k c^(3/2) is F = k c_max^(3/2) t^3, which the cubic Hermite interpolation in t
  reproduces exactly, and the nodes cluster at small c, where the discrete contact starts
  from a single element. Slopes dF/dt at the nodes come from the solver's contact stiffness
  (dF/dt = 2 c_max t dF/ddelta), so the interpolant is C1 in delta with exact node
  derivatives.
* Catmull-Rom cubic interpolation in s over 4 columns (s = 0 is a node; near the kinks of a
  new flat's onset it degrades to about linear accuracy). Outside the tabulated s range the
  end columns apply; the range is wide enough that they are the smooth wheel exactly (on the
  same grid).

Build: one :func:`wfjax.contact.kalker.solve` per node, warm-started along c (pressures and the
stiffness solve), sequential along each column; a concrete build starts each solve from the
previous pressure plus its first-order change E* dc z (z = dq/ddelta from the stiffness solve),
and takes the first compressions of a column whose flat is still outside the rigid overlap
from the table's last column, the smooth wheel (:func:`shared_prefix`: the same problem). A
concrete flat's solves each run on a window of the table grid around its own rigid overlap
(:func:`window_plan`: the same problem, since the contact lies inside the overlap; 2-3.5x
faster than the whole grid), with a few window sizes,
each one compiled solver (:func:`window_solver`) shared by every table and family node of the
process; a host loop drives each column, and the columns of all tables built together
(:func:`build_tables_3d`) are spread over the CPU cores. Traced flats or materials
(gradients) and batched columns (``batch_size`` > 1, for GPUs: ``lax.map`` over s with ``vmap``
chunks; on this 2-core CPU a ``vmap`` over all columns was 4.5x slower, because every batched
while-loop runs until its slowest lane) solve on the whole grid in one program.
Symmetric flats (new, rounded) are solved for s >= 0 only and mirrored
(the grid is symmetric, so this is exact). Gradients of the table values with respect to the
flat's depth and length flow through the implicit-differentiated solves.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._parallel import core_pool
from .._xla import array_module, to_device
from ..params import Flat, Material
from . import influence, kalker
from .interpolation import ContactTable
from .table_spec import (
    TableSpec,
    column_outputs,
    compression_nodes,
    table_spec,
    whole_grid_column,
)
from .windows import (
    COST_PER_WINDOW_SIZE,
    MAX_WINDOW_SIZES,
    TABLE_WINDOW_MARGIN,
    assign_windows,
    boxes_from_gaps,
    column_gaps,
    merge_sizes,
    needed_sizes,
    solve_cost,
    solver_inputs,
    window_solver,
)

_DEFAULT_MATERIAL = Material()

__all__ = ["ContactTable", "TableSpec", "table_spec", "build_table_3d", "build_tables_3d",
           "window_solver"]


# ----------------------------------------------------------------------------------------
# Potential contact areas: every solve on a window around its own rigid overlap
# ----------------------------------------------------------------------------------------


def build_columns(spec: TableSpec, flat: Flat, material: Material, s_values, tol: float,
                  batch_size: int = 1):
    """Solve the columns of a table at flat positions ``s_values`` [n] [m] on the whole grid
    (traceable: traced flats and materials, gradients; ``batch_size`` > 1 vmaps chunks of
    columns, for wide devices). Concrete builds use windows (:func:`build_tables_3d`).

    Returns:
        (onset [n] [m], force [n, n_t] [N], slope [n, n_t] [N], converged [n]) as in
        :class:`ContactTable`.
    """
    return jax.lax.map(lambda s: whole_grid_column(spec, flat, material, s, tol),
                       jnp.asarray(s_values), batch_size=batch_size)


# ----------------------------------------------------------------------------------------
# Concrete builds: one compiled solver per window size, shared by every build of the process
# ----------------------------------------------------------------------------------------


class SolvedColumn(NamedTuple):
    """One column's solves (host arrays): force [N] and stiffness dF/ddelta [N/m], [n_t - 1]
    each, all converged, and, when kept, the pressure [Pa] and the stiffness solve's z [1/m]
    on the whole grid after each solve, [n_t - 1, 2, nx, ny] (else None)."""

    force: np.ndarray
    stiffness: np.ndarray
    converged: bool
    warm: np.ndarray | None


def shared_prefix(gaps: np.ndarray, onsets: np.ndarray, compressions) -> np.ndarray:
    """[n] how many of each column's first compressions have the last column's solution.

    Column i at compression c has the reference's (last column's) contact problem when its
    onset is the reference's (the same approach onset + c), its gap is nowhere below the
    reference's and equals it on the reference's rigid overlap {gap_ref < onset + c}: the
    reference's pressure is then zero where the gaps differ and the gap is larger there, so
    it solves column i's problem too (the solution is unique). At a table's end the last
    column is the smooth wheel: the columns whose flat is still outside the overlap at small
    compressions share them (about a fifth of the default sweep's solves).

    Args:
        gaps: [n, nx, ny] gap [m] of the columns on one grid; onsets: [n] onset [m].
        compressions: [n_c] ascending compressions c [m].

    Returns:
        [n] int; the last column's entry is 0 (it is solved).
    """
    ref_gap, ref_onset = gaps[-1], onsets[-1]
    eligible = (onsets == ref_onset) & np.all(gaps >= ref_gap, axis=(1, 2))
    # the lowest reference gap where the column's gap differs: the reference's overlap stays
    # below it up to c = that - onset
    differ = np.min(np.where(gaps == ref_gap, np.inf, ref_gap), axis=(1, 2))
    count = np.searchsorted(np.asarray(compressions), differ - ref_onset, side="left")
    count = np.where(eligible, count, 0)
    count[-1] = 0
    return count


def solved_mask(shared: np.ndarray, n_c: int) -> np.ndarray:
    """[n, n_c] True for the solves that run: each column's compressions from its shared
    prefix (:func:`shared_prefix`, [n]) on."""
    return np.arange(n_c)[None, :] >= np.asarray(shared)[:, None]


def _solve_column(solvers, sizes, gap: np.ndarray, onset: float, compressions, size_index,
                  x0, y0, material, estar: float, shared: int = 0,
                  reference: SolvedColumn | None = None, keep: bool = False) -> SolvedColumn:
    """One column, each compression on its window (host loop).

    The first ``shared`` compressions come from ``reference`` (:func:`shared_prefix`), which
    also warm-starts the next solve. Each solve starts from the previous pressure plus the
    first-order change with the approach, E* dc z (z = dq/ddelta on the previous contact
    area, which the stiffness solve gives: about 15 % fewer CG iterations), and its stiffness
    solve from the previous z. ``estar``: E* [Pa]. ``keep`` (with ``shared`` = 0): return the
    whole-grid pressures and z after every solve (a reference for other columns).
    """
    if keep and shared:
        raise ValueError("a reference column (keep=True) is solved whole: shared must be 0")
    n_c = len(compressions)
    gpz = np.zeros((3,) + gap.shape, gap.dtype)  # gap, then the warm starts p and z
    gpz[0] = gap
    out = np.zeros((n_c, 3))
    warm = np.zeros((n_c, 2) + gap.shape, gap.dtype) if keep else None
    if shared:
        out[:shared] = np.stack([reference.force[:shared], reference.stiffness[:shared],
                                 np.ones(shared)], axis=-1)
        gpz[1:] = reference.warm[shared - 1]
    for j in range(shared, n_c):
        c = compressions[j]
        if j:
            gpz[1] += estar * (c - compressions[j - 1]) * gpz[2]
        k = int(size_index[j])
        wx, wy = sizes[k]
        window = np.s_[:, int(x0[j]):int(x0[j]) + wx, int(y0[j]):int(y0[j]) + wy]
        pz, out[j] = solvers[k](gpz[window], gap.dtype.type(onset + c), material)
        gpz[1:] = 0.0
        gpz[(np.s_[1:],) + window[1:]] = pz
        if keep:
            warm[j] = gpz[1:]
    return SolvedColumn(out[:, 0], out[:, 1], bool(np.all(out[:, 2] == 1.0)), warm)


def _grid_sizes(spec: TableSpec, sizes) -> tuple[tuple[int, int], ...]:
    """``sizes`` clipped to the grid of ``spec`` (a window never exceeds its grid)."""
    return tuple(dict.fromkeys((min(wx, spec.nx), min(wy, spec.ny)) for wx, wy in sizes))


# The CG tolerance of concrete (windowed) builds unless one is given. Their solves run in
# float32, which reaches it, at this tolerance or a looser one; a tighter one solves in float64.
# Against float64 at 1e-8 the default sweep's tables move by 8e-7 of their largest force
# (slopes: median 6e-8, 4 of 4,256 nodes 1e-3, an edge element's flip) and its max and min
# forces by 2e-6 and 7e-6; the build costs 29 % less CPU (docs/convergence.md).
WINDOWED_TOL = 1e-6
WHOLE_GRID_TOL = 1e-8  # the CG tolerance of whole-grid (traced, batched) builds


def _build_windowed(specs, flats, material: Material, tol: float,
                    max_sizes: int = MAX_WINDOW_SIZES) -> list[ContactTable]:
    """:func:`build_tables_3d` of concrete flats: every solve on its window, the window sizes
    merged over all the tables (:func:`merge_sizes`), the solvers from :func:`window_solver`
    and the columns of all tables as items of :func:`wfjax._parallel.core_pool`: each table's
    last column first (the smooth wheel: the others share its solves where the flat is
    still outside the overlap, :func:`shared_prefix`), then the most expensive first (so the
    cores stay busy whatever the tables' sizes)."""
    columns = [(spec, _solve_positions(spec)) for spec in specs]
    gaps = [column_gaps(spec, flat, s) for (spec, s), flat in zip(columns, flats, strict=True)]
    if tol >= WINDOWED_TOL:  # the solves in float32 (the table's values stay float64)
        gaps = [(g.astype(np.float32), onsets) for g, onsets in gaps]
    shared = [shared_prefix(g, onsets, compression_nodes(spec))
              for spec, (g, onsets) in zip(specs, gaps, strict=True)]
    solved = [solved_mask(n, spec.n_t - 1) for spec, n in zip(specs, shared, strict=True)]
    boxes = [boxes_from_gaps(spec, g - g.min(axis=(1, 2), keepdims=True), TABLE_WINDOW_MARGIN)
             for spec, (g, _) in zip(specs, gaps, strict=True)]
    merged = merge_sizes(needed_sizes(boxes, solved), max_sizes, COST_PER_WINDOW_SIZE)
    plans = [assign_windows(spec, b, _grid_sizes(spec, merged))
             for spec, b in zip(specs, boxes, strict=True)]
    dtype = gaps[0][0].dtype
    mat = solver_inputs(material, dtype)
    estar = float(influence.combined_modulus(material))
    pool = core_pool()
    h = {spec.element_size for spec in specs}.pop()
    compiled = {size: pool.submit(window_solver, size, h, tol, dtype)
                for size in dict.fromkeys(size for plan in plans for size in plan.sizes)}
    references = {}

    def column(item):
        t, i = item
        plan, (g, onsets), n_shared = plans[t], gaps[t], int(shared[t][i])
        last = i == len(onsets) - 1
        solvers = [compiled[size].result() for size in plan.sizes]
        return _solve_column(solvers, plan.sizes, g[i], onsets[i], compression_nodes(specs[t]),
                             plan.size_index[i], plan.x0[i], plan.y0[i], mat, estar,
                             n_shared, references[t].result() if n_shared else None,
                             keep=last and bool(np.any(shared[t])))

    futures = {}
    for t, (_, s) in enumerate(columns):  # the references first: the others wait for them
        futures[t, len(s) - 1] = references[t] = pool.submit(column, (t, len(s) - 1))
    cost = {(t, i): c for t, plan in enumerate(plans)
            for i, c in enumerate(np.sum(solved[t] * solve_cost(
                *np.moveaxis(np.asarray(plan.sizes)[plan.size_index], -1, 0)), axis=1))
            if (t, i) not in futures}
    futures.update({item: pool.submit(column, item)
                    for item in sorted(cost, key=cost.get, reverse=True)})
    tables = []
    for t, (spec, s) in enumerate(columns):
        solved_t = [futures[t, i].result() for i in range(len(s))]
        force_t, slope_t = column_outputs(spec, np.stack([c.force for c in solved_t]),
                                           np.stack([c.stiffness for c in solved_t]))
        table = _assemble(spec, gaps[t][1], force_t, slope_t,
                          all(c.converged for c in solved_t))
        tables.append(jax.tree.map(to_device, table))
    return tables


def _solve_positions(spec: TableSpec) -> np.ndarray:
    """Flat positions [m] of the solved columns (s >= 0 only for symmetric flats)."""
    return spec.s[spec.n_s // 2:] if spec.symmetric else spec.s


@functools.partial(jax.jit, static_argnums=(0, 3, 4))
def _build(spec: TableSpec, flat: Flat, material: Material, tol: float, batch_size: int):
    onset, force, slope, ok = build_columns(spec, flat, material, _solve_positions(spec), tol,
                                            batch_size)
    return _assemble(spec, onset, force, slope, jnp.all(ok))


def _assemble(spec: TableSpec, onset, force, slope, ok) -> ContactTable:
    """The table from its solved columns (mirrored for symmetric flats)."""
    xp = array_module(force)
    if spec.symmetric:
        def mirror(a):
            return xp.concatenate([a[:0:-1], a], axis=0)

        onset, force, slope = mirror(onset), mirror(force), mirror(slope)
    return ContactTable(
        s_min=xp.asarray(-spec.phi_max), ds=xp.asarray(2 * spec.phi_max / (spec.n_s - 1)),
        c_max=xp.asarray(spec.c_max), onset=onset, force=force, slope=slope,
        converged=xp.asarray(ok).astype(force.dtype), stretch=xp.asarray(spec.stretch))


def build_table_3d(flat: Flat, wheel_radius: float = 0.45, rail_head_radius: float = 0.45,
                   material: Material = _DEFAULT_MATERIAL, element_size: float = 1e-3,
                   max_force: float = 600e3, ds: float | None = None, n_t: int = 16,
                   spec: TableSpec | None = None, tol: float | None = None,
                   batch_size: int = 1, windows: bool = True) -> ContactTable:
    """Build the 3D contact table F3D(delta, s) of ``flat`` (see the module docstring).

    Args:
        flat: the flat. Its depth/length may be traced (``grad``) when ``spec`` is given.
        wheel_radius, rail_head_radius: R_W, R_R [m] (the flat's transverse arcs use R_R).
        material: wheel and rail material (may be traced).
        element_size: square contact element side [m].
        max_force: largest force to cover [N].
        ds: column spacing [m] (default ``element_size``); n_t: nodes along the compression.
        spec: a precomputed :func:`table_spec` (required when ``flat`` holds tracers).
        tol: relative CG tolerance of the solves (default: :data:`WINDOWED_TOL` for a
            windowed build, in float32 at it or looser, float64 tighter;
            :data:`WHOLE_GRID_TOL` on the whole grid, in the inputs' precision).
        batch_size: columns solved together by ``vmap`` (> 1 for wide devices; then every
            solve runs on the whole grid).
        windows: solve each compression on a window around its rigid overlap
            (:func:`window_plan`; same forces, several times faster) when the flat and the
            material are concrete and ``batch_size`` is 1; False: always the whole grid.

    Returns:
        :class:`ContactTable` with n_s columns of n_t nodes.
    """
    if spec is None:
        spec = table_spec(flat, wheel_radius, rail_head_radius, material, element_size,
                          max_force, ds, n_t)
    if windows and int(batch_size) == 1 and kalker._is_concrete_tree((flat, material)):
        return _build_windowed([spec], [flat], material,
                               WINDOWED_TOL if tol is None else float(tol))[0]
    return _build(spec, flat, material, WHOLE_GRID_TOL if tol is None else float(tol),
                  int(batch_size))


def build_tables_3d(flats, wheel_radius: float = 0.45, rail_head_radius: float = 0.45,
                    material: Material = _DEFAULT_MATERIAL, element_size: float = 1e-3,
                    max_force: float = 600e3,
                    tol: float = WINDOWED_TOL) -> list[ContactTable]:
    """:func:`build_table_3d` of several concrete flats, built together: one set of window
    sizes for all (each size compiles once), their columns spread over the CPU cores.

    A table's values depend on its windows only within the solver's tolerance ``tol``
    (relative; float32 solves at :data:`WINDOWED_TOL` or looser, see :func:`build_table_3d`),
    so a table built with others equals the one built alone to that.
    """
    flats = list(flats)
    if not kalker._is_concrete_tree((flats, material)):
        raise ValueError("build_tables_3d needs concrete flats and material; build a traced "
                         "flat's table with build_table_3d(spec=...)")
    specs = [table_spec(f, wheel_radius, rail_head_radius, material, element_size, max_force)
             for f in flats]
    if not flats:
        return []
    return _build_windowed(specs, flats, material, float(tol))



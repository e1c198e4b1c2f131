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

import concurrent.futures
import functools
import math
import threading
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._parallel import core_pool
from .._xla import SOLVER_COMPILER_OPTIONS, cpu_only, to_device
from ..params import Flat, Material
from . import kalker

__all__ = ["ContactTable", "Column", "TableSpec", "table_spec", "build_table_3d",
           "build_tables_3d", "table_force", "table_onset", "table_column", "column_force",
           "window_plan", "window_solve", "window_solver", "pad_columns"]

_DEFAULT_MATERIAL = Material()


class TableSpec(NamedTuple):
    """Static layout of a contact table (hashable; concrete numbers).

    Attributes:
        nx, ny: contact grid (odd; element centred on the nominal contact point).
        element_size: square element side [m].
        s_max: the table spans s in [-s_max, s_max] [m].
        n_s: number of s nodes (odd; s = 0 is a node).
        c_max: largest tabulated compression [m].
        n_t: number of nodes along t = sqrt(c / c_max).
        symmetric: solve s >= 0 only and mirror (symmetric flats).
        wheel_radius, rail_head_radius: R_W, R_R [m].
    """

    nx: int
    ny: int
    element_size: float
    s_max: float
    n_s: int
    c_max: float
    n_t: int
    symmetric: bool
    wheel_radius: float
    rail_head_radius: float

    @property
    def x(self) -> np.ndarray:
        """[nx] element centres along x [m]."""
        return (np.arange(self.nx) - (self.nx - 1) / 2) * self.element_size

    @property
    def y(self) -> np.ndarray:
        """[ny] element centres along y [m]."""
        return (np.arange(self.ny) - (self.ny - 1) / 2) * self.element_size

    @property
    def s(self) -> np.ndarray:
        """[n_s] flat positions of the columns [m]."""
        return np.linspace(-self.s_max, self.s_max, self.n_s)


class ContactTable(NamedTuple):
    """F3D(delta, s) table (a pytree of arrays; see the module docstring).

    Attributes:
        s_min: first column position [m] (scalar).
        ds: column spacing [m] (scalar).
        c_max: compression of the last t node [m] (scalar).
        onset: [n_s] rigid contact onset delta0(s) [m].
        force: [n_s, n_t] force [N] at c = c_max (j / (n_t - 1))^2.
        slope: [n_s, n_t] dF/du [N] per node index u = t (n_t - 1).
        converged: 1.0 when every solve of the build converged, else 0.0 (scalar).
    """

    s_min: Any
    ds: Any
    c_max: Any
    onset: Any
    force: Any
    slope: Any
    converged: Any


def table_spec(flat: Flat, wheel_radius: float = 0.45, rail_head_radius: float = 0.45,
               material: Material = _DEFAULT_MATERIAL, element_size: float = 1e-3,
               max_force: float = 600e3, ds: float | None = None, n_t: int = 16,
               max_compression: float | None = None) -> TableSpec:
    """Choose the layout of a contact table for ``flat`` (concrete inputs).

    Args:
        flat: the flat (concrete depth and length).
        wheel_radius, rail_head_radius: R_W, R_R [m].
        material: wheel and rail material.
        element_size: square contact element side [m].
        max_force: largest force the table must cover [N]; the compression range is
            1.4 x the Hertz approach at this force unless ``max_compression`` [m] is given
            (the sharp edges of a new flat are softer than Hertz: 1.25 x covered only 593 kN).
        ds: column spacing [m]; default ``element_size``.
        n_t: nodes along the compression axis.

    Returns:
        :class:`TableSpec`.
    """
    h = float(element_size)
    if not math.isfinite(h) or h <= 0:
        raise ValueError(f"element_size must be > 0 m, got {element_size!r}")
    ds = h if ds is None else float(ds)
    if not math.isfinite(ds) or ds <= 0:
        raise ValueError(f"ds must be > 0 m, got {ds!r}")
    if int(n_t) < 4:
        raise ValueError(f"n_t must be >= 4, got {n_t!r}")
    _, _, d_hertz, _ = kalker.elliptic_hertz(max_force, wheel_radius, rail_head_radius,
                                             material)
    c_max = 1.4 * d_hertz if max_compression is None else float(max_compression)
    x, y = kalker.contact_grid(flat, wheel_radius, rail_head_radius, material,
                               max_compression=c_max, max_force=max_force, element_size=h)
    half = 0.0 if flat.kind == "none" else flat.half_extent
    # Beyond |s| = half + sqrt(2 R_W c_max) the flat is outside the rigid overlap of every
    # tabulated compression, so the column equals the smooth wheel exactly.
    reach = half + math.sqrt(2 * float(wheel_radius) * c_max) + 2 * h
    n_half = max(1, math.ceil(reach / ds))
    return TableSpec(nx=len(x), ny=len(y), element_size=h, s_max=n_half * ds,
                     n_s=2 * n_half + 1, c_max=c_max, n_t=int(n_t),
                     symmetric=flat.kind in ("new", "rounded", "none"),
                     wheel_radius=float(wheel_radius), rail_head_radius=float(rail_head_radius))


def _onset(spec: TableSpec, flat: Flat, s, xp=jnp):
    """Continuum rigid contact onset min_x' gap(x', 0; s) [m] (smooth in s; differentiable).

    The minimum over y is at y = 0 (the flat's transverse arcs follow the rail head), so a 1D
    search suffices: a grid at 1/8 element across the contact grid, refined to 1/256 element
    around its minimiser (the minimiser is held fixed for the gradient: envelope theorem), and
    the chord ends of a new flat (corners of the gap). ``xp``: jnp (traceable) or np (a
    concrete flat's leaves and s; ``s`` may then be [n], the onsets [n]).
    """
    from ..model.geometry import _deviation

    hold = jax.lax.stop_gradient if xp is jnp else np.asarray
    s = xp.asarray(s)[..., None]
    rw = spec.wheel_radius
    half = (spec.nx - 1) / 2 * spec.element_size
    step = spec.element_size / 8

    def g1d(x):  # [..., m] gap along y = 0 at x [..., m]
        return rw - xp.sqrt(rw**2 - x**2) + _deviation(flat, x + s, xp)

    xs = np.arange(-8 * (spec.nx - 1) // 2, 8 * (spec.nx - 1) // 2 + 1) * step
    x0 = hold(xp.asarray(xs)[xp.argmin(g1d(xs), axis=-1)])[..., None]
    xf = xp.clip(x0 + np.linspace(-step, step, 65), -half, half)
    onset = xp.min(g1d(hold(xf)), axis=-1)
    if flat.kind == "new":
        # The chord ends are corners of the gap, often its minimum: a grid minimum misses a
        # corner by up to |slope| x spacing (~0.4 um at 2 mm elements). They move with the
        # depth and keep their gradient.
        edge = flat.wheel_radius * xp.arccos(1.0 - flat.depth / flat.wheel_radius)
        ends = xp.clip(xp.concatenate([edge - s, -edge - s], axis=-1), -half, half)
        onset = xp.minimum(onset, xp.min(g1d(ends), axis=-1))
    return onset


def _column(spec: TableSpec, flat: Flat, material: Material, s, tol: float):
    """Forces, stiffnesses and convergence along the t axis for one flat position s
    (every solve on the whole table grid)."""
    x, y = spec.x, spec.y
    h = spec.element_size
    gap = kalker.gap_3d(flat, s, x, y, spec.wheel_radius, spec.rail_head_radius)
    onset = _onset(spec, flat, s)
    cfg = kalker._Config(spec.nx, spec.ny, h, h, "fft", tol, 1000)

    def step(carry, c):
        p_prev, z_prev = carry
        r, z = kalker._solve_impl(cfg, gap, material, onset + c, None, p_prev, 50, True, False,
                                  z_init=z_prev)
        return (r.pressure, z), (r.force, r.stiffness, r.diagnostics.converged)

    p0 = jnp.zeros((spec.nx, spec.ny), gap.dtype)
    _, (f, k, ok) = jax.lax.scan(step, (p0, p0), jnp.asarray(_compressions(spec)))
    return (onset,) + _column_outputs(spec, f, k) + (jnp.all(ok),)


def _compressions(spec: TableSpec) -> np.ndarray:
    """[n_t - 1] compressions c_j = c_max t_j^2 of the solved t nodes (t_0 = 0 is F = 0)."""
    return spec.c_max * np.linspace(0.0, 1.0, spec.n_t)[1:] ** 2


def _xp(a):
    """numpy for host arrays (the concrete builds: no op-by-op compilations), else jnp."""
    return np if isinstance(a, np.ndarray) else jnp


def _column_outputs(spec: TableSpec, f, k):
    """Node forces and slopes dF/du [..., n_t] from the solved forces f and stiffnesses k
    [..., n_t - 1]."""
    xp = _xp(f)
    t = np.linspace(0.0, 1.0, spec.n_t)[1:]
    zero = xp.zeros(f.shape[:-1] + (1,), f.dtype)
    return (xp.concatenate([zero, f], axis=-1),
            xp.concatenate([zero, k * 2 * spec.c_max * t / (spec.n_t - 1)], axis=-1))


# ----------------------------------------------------------------------------------------
# Potential contact areas: every solve on a window around its own rigid overlap
# ----------------------------------------------------------------------------------------


class WindowPlan(NamedTuple):
    """Where each solve of a table build runs: a window of the table grid around its rigid
    overlap (concrete numbers).

    The contact at approach delta lies inside the rigid overlap {gap < delta} (the surface
    displacements are >= 0), so a solve on a window that contains the overlap is the same
    problem as on the whole grid: the elements left out carry no pressure there. The windows
    come in a few static sizes, one compiled solver each, chosen per solve by ``lax.switch``.

    Attributes:
        sizes: the window sizes (wx, wy) [elements], cheapest first (static).
        size_index: [n_columns, n_t - 1] which size each solve uses.
        x0, y0: [n_columns, n_t - 1] grid index of each window's first element along x, y.
    """

    sizes: tuple[tuple[int, int], ...]
    size_index: np.ndarray
    x0: np.ndarray
    y0: np.ndarray


WINDOW_MARGIN = 2  # elements between the rigid overlap's bounding box and the window edge
# A table's solve at approach onset + c has its contact inside {gap < onset + c} (u >= 0, so
# h = gap - delta + u > 0 elsewhere), a subset of {gap - min(gap) < c}: its windows need no
# margin (the direct mode's solves, between the columns, keep WINDOW_MARGIN).
TABLE_WINDOW_MARGIN = 0
MAX_WINDOW_SIZES = 4  # static window sizes per build, at most
# One more window size (one more compiled solver: ~1 CPU-s to trace and compile on the 2-core
# CPU) must save at least this much modelled solve cost (FFT size m times log m, summed over
# the solves): measured ~2.2e-8 CPU-s per unit there (the default sweep's two tables, 1533
# solves, 2.0 CPU-s warm). 2e7 (from 5e-8 s per unit before the solver's speed-ups) chose 3
# sizes for them and built 0.4-0.9 s slower from cold than this, which chooses 2.
COST_PER_WINDOW_SIZE = 5e7


@functools.lru_cache(maxsize=8)
def _fft_lengths(n_max: int) -> np.ndarray:
    """[n_max + 1] FFT length of a window of n elements, n = 0..n_max."""
    return np.array([kalker._fft_length(max(n, 1)) for n in range(n_max + 1)])


def _solve_cost(wx, wy):
    """Modelled cost of a solve on a wx x wy window: its FFT size m times log m (arrays)."""
    lengths = _fft_lengths(1024 * (1 + int(max(np.max(wx), np.max(wy))) // 1024))
    m = (lengths[wx] * lengths[wy]).astype(float)
    return m * np.log(m)


@functools.lru_cache(maxsize=256)
def _size_ladder(n: int) -> tuple[int, ...]:
    """Window lengths worth using along an axis of n elements: for each FFT length the largest
    window it serves (a longer window costs nothing more in FFTs), and n itself."""
    return tuple(sorted({min(n, (kalker._fft_length(w) + 1) // 2) for w in range(1, n + 1)}))


def _merge_sizes(needed: dict[tuple[int, int], int], max_sizes: int,
                 cost_per_size: float) -> list[tuple[int, int]]:
    """Window sizes covering ``needed`` (size -> solve count): greedily join the two sizes
    whose union (elementwise max) adds the least cost while more than ``max_sizes`` remain,
    or while the join costs less than ``cost_per_size``.

    The pairwise costs are kept in a matrix and only a join's row is recomputed (the default
    sweep's ~300 sizes: 0.1 s to recompute them all at every join, ~10 ms this way).
    """
    w = np.array(list(needed), dtype=int).reshape(-1, 2)
    count = np.array(list(needed.values()), dtype=float)
    alive = np.ones(len(w), bool)
    own = count * _solve_cost(w[:, 0], w[:, 1])

    def extra_with(k):  # [n] cost added by joining size k with each size (inf: itself, gone)
        union = np.maximum(w, w[k])
        e = (count + count[k]) * _solve_cost(union[:, 0], union[:, 1]) - own - own[k]
        e[~alive] = np.inf
        e[k] = np.inf
        return e

    extra = np.full((len(w), len(w)), np.inf)
    for k in range(len(w)):
        extra[k] = extra_with(k)
    while alive.sum() > 1:
        a, b = np.unravel_index(np.argmin(extra), extra.shape)
        if alive.sum() <= max_sizes and extra[a, b] > cost_per_size:
            break
        union = np.maximum(w[a], w[b])
        alive[[a, b]] = False
        extra[[a, b], :] = np.inf
        extra[:, [a, b]] = np.inf
        same = np.flatnonzero(alive & np.all(w == union, axis=1))  # a union may equal a size
        k = same[0] if len(same) else a  # the join lives on in that size, or in a's slot
        joined = count[a] + count[b]
        count[k] = joined if k == a else count[k] + joined
        w[k], alive[k] = union, True
        own[k] = count[k] * _solve_cost(w[k, 0], w[k, 1])
        extra[k] = extra[:, k] = extra_with(k)
    w = w[alive]
    order = np.argsort(_solve_cost(w[:, 0], w[:, 1]), kind="stable")
    return [(int(wx), int(wy)) for wx, wy in w[order]]


def _column_gaps(spec: TableSpec, flat: Flat, s_values) -> tuple[np.ndarray, np.ndarray]:
    """([n, nx, ny] gap [m] on the table grid, [n] rigid onset [m]) at concrete flat
    positions ``s_values`` [n] [m] of a concrete flat, in NumPy (nothing to compile)."""
    flat = jax.tree.map(np.asarray, flat)
    s_values = np.asarray(s_values, dtype=float)
    return (kalker._gap(flat, s_values, spec.x, spec.y, spec.wheel_radius,
                        spec.rail_head_radius, np), _onset(spec, flat, s_values, np))


def _relative_gaps(spec: TableSpec, flat: Flat, s_values) -> np.ndarray:
    """[n, nx, ny] gap minus its minimum on the grid [m] at concrete flat positions.

    The grid minimum is >= the continuum onset, so {gap - min < c} contains the rigid overlap
    at compression c (a window from it is never too small).
    """
    gaps = _column_gaps(spec, flat, s_values)[0]
    return gaps - gaps.min(axis=(1, 2), keepdims=True)


def window_plan(spec: TableSpec, flat: Flat, s_values, margin: int = WINDOW_MARGIN,
                max_sizes: int = MAX_WINDOW_SIZES,
                cost_per_size: float = COST_PER_WINDOW_SIZE) -> WindowPlan:
    """Windows of the solves of a table build for ``flat`` (concrete) at columns ``s_values``.

    Each solve's window covers the bounding box of its rigid overlap {gap - min(gap) < c} on
    the table grid plus ``margin`` elements (clipped to the grid); the sizes are rounded up to
    the largest window of their FFT length, then merged (:func:`_merge_sizes`).

    Args:
        spec: the table layout (its grid bounds every window).
        flat: the flat (concrete).
        s_values: [n] flat positions of the columns [m].
        margin: elements added on each side of the overlap's bounding box.
        max_sizes: static window sizes allowed.
        cost_per_size: modelled solve cost one more size must save (its compile time).

    Returns:
        :class:`WindowPlan` for the n columns x (n_t - 1) compressions.
    """
    boxes = overlap_boxes(spec, flat, s_values, margin)
    sizes = _merge_sizes(needed_sizes([boxes]), max_sizes, cost_per_size)
    return assign_windows(spec, boxes, sizes)


class OverlapBoxes(NamedTuple):
    """Bounding boxes of the solves' rigid overlaps on a table grid, [n_columns, n_t - 1]
    each: first/last grid index along x (xa, xb) and y (ya, yb), margin included, and the
    box's size rounded up to the largest window of its FFT length (wx, wy)."""

    xa: np.ndarray
    xb: np.ndarray
    ya: np.ndarray
    yb: np.ndarray
    wx: np.ndarray
    wy: np.ndarray


def overlap_boxes(spec: TableSpec, flat: Flat, s_values,
                  margin: int = WINDOW_MARGIN) -> OverlapBoxes:
    """The :class:`OverlapBoxes` of ``flat`` (concrete) at columns ``s_values`` [n] [m]."""
    return _boxes(spec, _relative_gaps(spec, flat, np.asarray(s_values, dtype=float)), margin)


def _boxes(spec: TableSpec, rel: np.ndarray, margin: int) -> OverlapBoxes:
    """:class:`OverlapBoxes` from the columns' relative gaps ``rel`` [n, nx, ny] [m]."""
    cs = _compressions(spec)
    boxes = []
    for axis, n in ((2, spec.nx), (1, spec.ny)):
        line_min = rel.min(axis=axis)  # [n_columns, n] along x (then y)
        inside = line_min[:, None, :] < cs[None, :, None]  # [n_columns, n_c, n]
        first = np.argmax(inside, axis=2)
        last = n - 1 - np.argmax(inside[:, :, ::-1], axis=2)
        lo, hi = np.maximum(first - margin, 0), np.minimum(last + margin, n - 1)
        ladder = np.asarray(_size_ladder(n))
        boxes.append((lo, hi, ladder[np.searchsorted(ladder, hi - lo + 1)]))
    (xa, xb, wx), (ya, yb, wy) = boxes
    return OverlapBoxes(xa, xb, ya, yb, wx, wy)


def needed_sizes(boxes: list[OverlapBoxes], solved=None) -> dict[tuple[int, int], int]:
    """Window size (wx, wy) -> number of solves that need it, over several builds.

    ``solved``: per build a [n_columns, n_t - 1] mask of the solves that run
    (:func:`solved_mask`; default all)."""
    solved = [np.ones(b.wx.shape, bool) for b in boxes] if solved is None else solved
    w = np.concatenate([np.stack([b.wx, b.wy], -1)[m] for b, m in zip(boxes, solved,
                                                                       strict=True)])
    sizes, counts = np.unique(w, axis=0, return_counts=True)
    return {(int(a), int(b)): int(c) for (a, b), c in zip(sizes, counts, strict=True)}


def assign_windows(spec: TableSpec, boxes: OverlapBoxes, sizes) -> WindowPlan:
    """Each solve's cheapest window of ``sizes`` that holds its box, centred on the box and
    clipped to the grid of ``spec``."""
    w = np.asarray(sizes)
    cost = _solve_cost(w[:, 0], w[:, 1])
    fits = (w[None, None, :, 0] >= (boxes.xb - boxes.xa + 1)[..., None]) & \
        (w[None, None, :, 1] >= (boxes.yb - boxes.ya + 1)[..., None])
    size_index = np.argmin(np.where(fits, cost, np.inf), axis=-1).astype(np.int32)
    sx, sy = w[size_index, 0], w[size_index, 1]
    x0 = np.clip((boxes.xa + boxes.xb + 1) // 2 - sx // 2, 0, spec.nx - sx).astype(np.int32)
    y0 = np.clip((boxes.ya + boxes.yb + 1) // 2 - sy // 2, 0, spec.ny - sy).astype(np.int32)
    return WindowPlan(tuple((int(a), int(b)) for a, b in w), size_index, x0, y0)


def window_solve(spec: TableSpec, flat: Flat, material: Material, s, approach, size, start,
                 p_full, tol: float, z_full=None, rough_x=None):
    """One approach-controlled Kalker solve on a window of the grid of ``spec`` (traceable).

    Args:
        spec: the layout whose grid the window cuts. flat, material: as for :func:`gap_3d`.
        s: flat position [m]; approach: delta [m].
        size: (wx, wy) window size [elements] (static). start: (i0, j0) grid index of its
            first element (may be traced).
        p_full: [nx, ny] whole-grid pressure [Pa] of the warm start.
        tol: CG tolerance. z_full: [nx, ny] whole-grid warm start of the stiffness solve, or
            None (cold). rough_x: [nx] rail + wheel roughness [m] along x' (positive =
            surface raised: taken off the gap), or None.

    Returns:
        (:class:`wfjax.contact.kalker.KalkerResult` on the window, the window's gap [wx, wy] m,
        the pressure embedded in the whole grid [nx, ny] Pa, the stiffness solve's z embedded
        likewise, or None when ``z_full`` is None).
    """
    (wx, wy), (i0, j0) = size, start
    h = spec.element_size
    x = jax.lax.dynamic_slice(jnp.asarray(spec.x), (i0,), (wx,))
    y = jax.lax.dynamic_slice(jnp.asarray(spec.y), (j0,), (wy,))
    gap = kalker.gap_3d(flat, s, x, y, spec.wheel_radius, spec.rail_head_radius)
    if rough_x is not None:
        gap = gap - jax.lax.dynamic_slice(rough_x, (i0,), (wx,))[:, None]
    cfg = kalker._Config(wx, wy, h, h, "fft", tol, 1000)
    z0 = None if z_full is None else jax.lax.dynamic_slice(z_full, (i0, j0), (wx, wy))
    r, z = kalker._solve_impl(cfg, gap, material, approach, None,
                              jax.lax.dynamic_slice(p_full, (i0, j0), (wx, wy)), 50, True,
                              False, z_init=z0)

    def embed(window, full):
        return jax.lax.dynamic_update_slice(jnp.zeros_like(full), window.astype(full.dtype),
                                            (i0, j0))

    return r, gap, embed(r.pressure, p_full), None if z_full is None else embed(z, z_full)


def build_columns(spec: TableSpec, flat: Flat, material: Material, s_values, tol: float,
                  batch_size: int = 1):
    """Solve the columns of a table at flat positions ``s_values`` [n] [m] on the whole grid
    (traceable: traced flats and materials, gradients; ``batch_size`` > 1 vmaps chunks of
    columns, for wide devices). Concrete builds use windows (:func:`build_tables_3d`).

    Returns:
        (onset [n] [m], force [n, n_t] [N], slope [n, n_t] [N], converged [n]) as in
        :class:`ContactTable`.
    """
    return jax.lax.map(lambda s: _column(spec, flat, material, s, tol), jnp.asarray(s_values),
                       batch_size=batch_size)


# ----------------------------------------------------------------------------------------
# Concrete builds: one compiled solver per window size, shared by every build of the process
# ----------------------------------------------------------------------------------------

_SOLVERS: dict[tuple, concurrent.futures.Future] = {}
_SOLVERS_LOCK = threading.Lock()


def _solver_inputs(material: Material, dtype) -> Material:
    return jax.tree.map(lambda v: to_device(v, dtype), material)


def window_solver(size: tuple[int, int], element_size: float, tol: float, dtype=np.float64):
    """The compiled approach-controlled Kalker solve on a window of ``size`` (wx, wy).

    ``solver(gpz, approach, material) -> (pz, out)`` with gpz [3, wx, wy] the gap [m] and
    the warm starts of the pressure [Pa] and of the stiffness solve z [1/m], approach [m], a
    material of ``dtype`` arrays (:func:`_solver_inputs`); pz [2, wx, wy] the pressure and z,
    out [3] the force [N], the stiffness [N/m] and 1.0 if converged (few arrays in and out:
    each costs the host loop a conversion). The
    program depends on nothing but the window, the element size, the tolerance and the
    dtype, so every table and family node of the process shares it: each size compiles once
    (~0.4 s on the 2-core CPU), however many flats use it; concurrent callers of a size wait
    for the first one's compilation.
    """
    key = (int(size[0]), int(size[1]), float(element_size), float(tol), np.dtype(dtype).name)
    with _SOLVERS_LOCK:
        future = _SOLVERS.get(key)
        mine = future is None
        if mine:
            future = _SOLVERS[key] = concurrent.futures.Future()
    if mine:
        try:
            future.set_result(_compile_window_solver(*key))
        except BaseException as err:
            with _SOLVERS_LOCK:
                del _SOLVERS[key]
            future.set_exception(err)
            raise
    return future.result()


def _compile_window_solver(wx: int, wy: int, h: float, tol: float, dtype: str):
    cfg = kalker._Config(wx, wy, h, h, "fft", tol, 1000)

    def solve(gpz, approach, material):
        r, z = kalker._solve_impl(cfg, gpz[0], material, approach, None, gpz[1], 50, True,
                                  False, z_init=gpz[2])
        return (jnp.stack([r.pressure, z]),
                jnp.stack([r.force, r.stiffness, r.diagnostics.converged.astype(dtype)]))

    def like(shape):  # lowered from shapes: no eager zeros, no compiled broadcast
        return jax.ShapeDtypeStruct(shape, dtype)

    return jax.jit(solve).lower(like((3, wx, wy)), like(()), jax.tree.map(
        lambda _: like(()), _DEFAULT_MATERIAL)).compile(
            compiler_options=cpu_only(SOLVER_COMPILER_OPTIONS))


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
    out = np.zeros((n_c, 3), gap.dtype)
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
        pz, out[j] = solvers[k](gpz[window], onset + c, material)
        gpz[1:] = 0.0
        gpz[(np.s_[1:],) + window[1:]] = pz
        if keep:
            warm[j] = gpz[1:]
    return SolvedColumn(out[:, 0], out[:, 1], bool(np.all(out[:, 2] == 1.0)), warm)


def _grid_sizes(spec: TableSpec, sizes) -> tuple[tuple[int, int], ...]:
    """``sizes`` clipped to the grid of ``spec`` (a window never exceeds its grid)."""
    return tuple(dict.fromkeys((min(wx, spec.nx), min(wy, spec.ny)) for wx, wy in sizes))


def _build_windowed(specs, flats, material: Material, tol: float,
                    max_sizes: int = MAX_WINDOW_SIZES) -> list[ContactTable]:
    """:func:`build_tables_3d` of concrete flats: every solve on its window, the window sizes
    merged over all the tables (:func:`_merge_sizes`), the solvers from :func:`window_solver`
    and the columns of all tables as items of :func:`wfjax._parallel.core_pool`: each table's
    last column first (the smooth wheel: the others share its solves where the flat is
    still outside the overlap, :func:`shared_prefix`), then the most expensive first (so the
    cores stay busy whatever the tables' sizes)."""
    columns = [(spec, _solve_positions(spec)) for spec in specs]
    gaps = [_column_gaps(spec, flat, s) for (spec, s), flat in zip(columns, flats, strict=True)]
    shared = [shared_prefix(g, onsets, _compressions(spec))
              for spec, (g, onsets) in zip(specs, gaps, strict=True)]
    solved = [solved_mask(n, spec.n_t - 1) for spec, n in zip(specs, shared, strict=True)]
    boxes = [_boxes(spec, g - g.min(axis=(1, 2), keepdims=True), TABLE_WINDOW_MARGIN)
             for spec, (g, _) in zip(specs, gaps, strict=True)]
    merged = _merge_sizes(needed_sizes(boxes, solved), max_sizes, COST_PER_WINDOW_SIZE)
    plans = [assign_windows(spec, b, _grid_sizes(spec, merged))
             for spec, b in zip(specs, boxes, strict=True)]
    dtype = gaps[0][0].dtype
    mat = _solver_inputs(material, dtype)
    estar = float(kalker.combined_modulus(material))
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
        return _solve_column(solvers, plan.sizes, g[i], onsets[i], _compressions(specs[t]),
                             plan.size_index[i], plan.x0[i], plan.y0[i], mat, estar,
                             n_shared, references[t].result() if n_shared else None,
                             keep=last and bool(np.any(shared[t])))

    futures = {}
    for t, (_, s) in enumerate(columns):  # the references first: the others wait for them
        futures[t, len(s) - 1] = references[t] = pool.submit(column, (t, len(s) - 1))
    cost = {(t, i): c for t, plan in enumerate(plans)
            for i, c in enumerate(np.sum(solved[t] * _solve_cost(
                *np.moveaxis(np.asarray(plan.sizes)[plan.size_index], -1, 0)), axis=1))
            if (t, i) not in futures}
    futures.update({item: pool.submit(column, item)
                    for item in sorted(cost, key=cost.get, reverse=True)})
    tables = []
    for t, (spec, s) in enumerate(columns):
        solved_t = [futures[t, i].result() for i in range(len(s))]
        force_t, slope_t = _column_outputs(spec, np.stack([c.force for c in solved_t]),
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
    xp = _xp(force)
    if spec.symmetric:
        def mirror(a):
            return xp.concatenate([a[:0:-1], a], axis=0)

        onset, force, slope = mirror(onset), mirror(force), mirror(slope)
    return ContactTable(
        s_min=xp.asarray(-spec.s_max), ds=xp.asarray(2 * spec.s_max / (spec.n_s - 1)),
        c_max=xp.asarray(spec.c_max), onset=onset, force=force, slope=slope,
        converged=xp.asarray(ok).astype(force.dtype))


def build_table_3d(flat: Flat, wheel_radius: float = 0.45, rail_head_radius: float = 0.45,
                   material: Material = _DEFAULT_MATERIAL, element_size: float = 1e-3,
                   max_force: float = 600e3, ds: float | None = None, n_t: int = 16,
                   spec: TableSpec | None = None, tol: float = 1e-8,
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
        tol: CG tolerance of the solves.
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
        return _build_windowed([spec], [flat], material, float(tol))[0]
    return _build(spec, flat, material, float(tol), int(batch_size))


def build_tables_3d(flats, wheel_radius: float = 0.45, rail_head_radius: float = 0.45,
                    material: Material = _DEFAULT_MATERIAL, element_size: float = 1e-3,
                    max_force: float = 600e3, tol: float = 1e-8) -> list[ContactTable]:
    """:func:`build_table_3d` of several concrete flats, built together: one set of window
    sizes for all (each size compiles once), their columns spread over the CPU cores.

    A table's values depend on its windows only within the solver's tolerance (about 1e-9
    of its largest force), so a table built with others equals the one built alone to that.
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


def pad_columns(table: ContactTable, n_s: int) -> ContactTable:
    """``table`` widened to ``n_s`` columns by repeating its end columns (half on either side).

    Beyond its s range a table's end columns apply (the smooth wheel), so the padded table
    gives the same forces, up to the rounding of the column coordinate (~1e-14 relative),
    with the shape of a larger table: the tables of different flats then stack into one
    batch, one compiled sweep program (:func:`wfjax.sweeps.sweep`).

    Args:
        table: a concrete :class:`ContactTable` with ``n <= n_s`` columns.
        n_s: the number of columns wanted.

    Returns:
        :class:`ContactTable` with ``n_s`` columns (numpy arrays).
    """
    n = int(np.shape(table.onset)[0])
    if int(n_s) < n:
        raise ValueError(f"n_s must be >= the table's {n} columns, got {n_s!r}")
    left = (int(n_s) - n) // 2
    widths = (left, int(n_s) - n - left)

    def pad(a):
        a = np.asarray(a)
        return np.pad(a, [widths] + [(0, 0)] * (a.ndim - 1), mode="edge")

    return table._replace(s_min=np.asarray(table.s_min) - left * np.asarray(table.ds),
                          onset=pad(table.onset), force=pad(table.force),
                          slope=pad(table.slope))


def catmull_rom_weights(w):
    """Catmull-Rom cubic weights [4, ...] of the nodes i-1, i, i+1, i+2 at fraction w in [0, 1)
    of the interval [i, i+1] (uniform nodes; they sum to 1 and reproduce quadratics)."""
    w2, w3 = w * w, w * w * w
    return 0.5 * jnp.stack([-w3 + 2 * w2 - w, 3 * w3 - 5 * w2 + 2, -3 * w3 + 4 * w2 + w,
                            w3 - w2])


def _locate_s(table: ContactTable, s):
    n_s = table.onset.shape[0]
    u = jnp.clip((s - table.s_min) / table.ds, 0.0, n_s - 1.0)
    i = jnp.clip(jnp.floor(u), 0, n_s - 2).astype(jnp.int32)
    weights = catmull_rom_weights(u - i)  # columns i-1, i, i+1, i+2 (clamped at the ends)
    cols = jnp.clip(i + jnp.arange(-1, 3), 0, n_s - 1)
    return cols, weights


def table_onset(table: ContactTable, s):
    """Rigid contact onset delta0(s) [m] (Catmull-Rom cubic in s). Scalar s [m] -> scalar."""
    cols, weights = _locate_s(table, s)
    return jnp.sum(weights * table.onset[cols])


def _hermite(f0, f1, m0, m1, w):
    w2, w3 = w * w, w * w * w
    return ((2 * w3 - 3 * w2 + 1) * f0 + (w3 - 2 * w2 + w) * m0 + (-2 * w3 + 3 * w2) * f1
            + (w3 - w2) * m1)


class Column(NamedTuple):
    """One compression column F(c) of a contact law at a fixed flat position (a pytree).

    The s-dependent half of a force evaluation (:func:`table_column`,
    :func:`wfjax.contact.family.family_column`); :func:`column_force` is the cheap
    delta-dependent half, so a time step interpolates in s once and iterates Newton on delta.

    Attributes:
        onset: rigid contact onset delta0 [m] (scalar); compression c = delta - onset.
        c_max: compression of the last t node [m] (scalar).
        force: [n_t] force [N] at c = c_max (j / (n_t - 1))^2.
        slope: [n_t] dF/du [N] per node index u = t (n_t - 1), t = sqrt(c / c_max).
    """

    onset: Any
    c_max: Any
    force: Any
    slope: Any


def table_column(table: ContactTable, s) -> Column:
    """The column of ``table`` at flat position ``s`` [m] (Catmull-Rom cubic in s, 4 columns).

    Pure jnp; differentiable with respect to s and the table's arrays. Beyond the s range the
    end columns (smooth wheel) apply.
    """
    cols, weights = _locate_s(table, s)
    onset = jnp.sum(weights * table.onset[cols])
    force = jnp.tensordot(weights, table.force[cols], axes=1)
    slope = jnp.tensordot(weights, table.slope[cols], axes=1)
    return Column(onset=onset, c_max=jnp.asarray(table.c_max), force=force, slope=slope)


def column_force(column: Column, delta):
    """Force F [N] of ``column`` at approach ``delta`` [m].

    Cubic Hermite in t = sqrt(c / c_max), c = delta - onset; F = 0 for c <= 0 with a zero
    gradient there (and F >= 0). Pure jnp and branch-free: ``jit``/``vmap``/``grad`` with
    respect to delta and the column's arrays. Beyond c_max the last interval's cubic
    extrapolates.
    """
    c = delta - column.onset
    pos = c > 0
    c_safe = jnp.where(pos, c, 1.0)
    n_t = column.force.shape[-1]
    u = jnp.sqrt(c_safe / column.c_max) * (n_t - 1)
    j = jnp.clip(jnp.floor(u), 0, n_t - 2).astype(jnp.int32)
    v = u - j
    f = _hermite(column.force[j], column.force[j + 1], column.slope[j], column.slope[j + 1], v)
    return jnp.where(pos, jnp.maximum(f, 0.0), 0.0)


def table_force(table: ContactTable, delta, s):
    """3D contact force F [N] at approach ``delta`` [m] and flat position ``s`` [m].

    ``column_force(table_column(table, s), delta)``: cubic Hermite in t = sqrt(c / c_max),
    c = delta - delta0(s), Catmull-Rom cubic in s (4 columns); F = 0 for c <= 0 with a zero
    gradient there. Pure jnp and branch-free: ``jit``/``vmap``/``grad`` with respect to delta,
    s and the table's arrays. Scalars in, scalar out (``vmap`` for batches). Beyond c_max the
    last interval's cubic extrapolates; beyond the s range the end columns (smooth wheel)
    apply.
    """
    return column_force(table_column(table, s), delta)

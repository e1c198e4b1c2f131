"""Windowed Kalker solves for contact tables: each solve runs on a window of the table grid around
its flat's rigid overlap (the contact lies inside it, so the problem is the same; 2-3.5x faster
than the whole grid), with a few window sizes per build, each one compiled solver shared by every
table and family node of the process."""

from __future__ import annotations

import concurrent.futures
import functools
import threading
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._xla import SOLVER_COMPILER_OPTIONS, cpu_only, to_device
from ..params import Flat, Material
from . import geometry3d, influence, kalker
from .table_spec import (
    TableSpec,
    compression_nodes,
    rigid_onset,
)

_DEFAULT_MATERIAL = Material()


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
    return np.array([influence.fft_length(max(n, 1)) for n in range(n_max + 1)])


def solve_cost(wx, wy):
    """Modelled cost of a solve on a wx x wy window: its FFT size m times log m (arrays)."""
    lengths = _fft_lengths(1024 * (1 + int(max(np.max(wx), np.max(wy))) // 1024))
    m = (lengths[wx] * lengths[wy]).astype(float)
    return m * np.log(m)


@functools.lru_cache(maxsize=256)
def _size_ladder(n: int) -> tuple[int, ...]:
    """Window lengths worth using along an axis of n elements: for each FFT length the largest
    window it serves (a longer window costs nothing more in FFTs), and n itself."""
    return tuple(sorted({min(n, (influence.fft_length(w) + 1) // 2) for w in range(1, n + 1)}))


def merge_sizes(needed: dict[tuple[int, int], int], max_sizes: int,
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
    own = count * solve_cost(w[:, 0], w[:, 1])

    def extra_with(k):  # [n] cost added by joining size k with each size (inf: itself, gone)
        union = np.maximum(w, w[k])
        e = (count + count[k]) * solve_cost(union[:, 0], union[:, 1]) - own - own[k]
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
        own[k] = count[k] * solve_cost(w[k, 0], w[k, 1])
        extra[k] = extra[:, k] = extra_with(k)
    w = w[alive]
    order = np.argsort(solve_cost(w[:, 0], w[:, 1]), kind="stable")
    return [(int(wx), int(wy)) for wx, wy in w[order]]


def column_gaps(spec: TableSpec, flat: Flat, s_values) -> tuple[np.ndarray, np.ndarray]:
    """([n, nx, ny] gap [m] on the table grid, [n] rigid onset [m]) at concrete flat
    positions ``s_values`` [n] [m] of a concrete flat, in NumPy (nothing to compile)."""
    flat = jax.tree.map(np.asarray, flat)
    s_values = np.asarray(s_values, dtype=float)
    return (geometry3d._gap(flat, s_values, spec.x, spec.y, spec.wheel_radius,
                        spec.rail_head_radius, np), rigid_onset(spec, flat, s_values, np))


def _relative_gaps(spec: TableSpec, flat: Flat, s_values) -> np.ndarray:
    """[n, nx, ny] gap minus its minimum on the grid [m] at concrete flat positions.

    The grid minimum is >= the continuum onset, so {gap - min < c} contains the rigid overlap
    at compression c (a window from it is never too small).
    """
    gaps = column_gaps(spec, flat, s_values)[0]
    return gaps - gaps.min(axis=(1, 2), keepdims=True)


def window_plan(spec: TableSpec, flat: Flat, s_values, margin: int = WINDOW_MARGIN,
                max_sizes: int = MAX_WINDOW_SIZES,
                cost_per_size: float = COST_PER_WINDOW_SIZE) -> WindowPlan:
    """Windows of the solves of a table build for ``flat`` (concrete) at columns ``s_values``.

    Each solve's window covers the bounding box of its rigid overlap {gap - min(gap) < c} on
    the table grid plus ``margin`` elements (clipped to the grid); the sizes are rounded up to
    the largest window of their FFT length, then merged (:func:`merge_sizes`).

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
    sizes = merge_sizes(needed_sizes([boxes]), max_sizes, cost_per_size)
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
    rel = _relative_gaps(spec, flat, np.asarray(s_values, dtype=float))
    return boxes_from_gaps(spec, rel, margin)


def boxes_from_gaps(spec: TableSpec, rel: np.ndarray, margin: int) -> OverlapBoxes:
    """:class:`OverlapBoxes` from the columns' relative gaps ``rel`` [n, nx, ny] [m]."""
    cs = compression_nodes(spec)
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
    cost = solve_cost(w[:, 0], w[:, 1])
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
    gap = geometry3d.gap_3d(flat, s, x, y, spec.wheel_radius, spec.rail_head_radius)
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


_SOLVERS: dict[tuple, concurrent.futures.Future] = {}


_SOLVERS_LOCK = threading.Lock()


def solver_inputs(material: Material, dtype) -> Material:
    return jax.tree.map(lambda v: to_device(v, dtype), material)


def window_solver(size: tuple[int, int], element_size: float, tol: float, dtype=np.float64):
    """The compiled approach-controlled Kalker solve on a window of ``size`` (wx, wy).

    ``solver(gpz, approach, material) -> (pz, out)`` with gpz [3, wx, wy] the gap [m] and
    the warm starts of the pressure [Pa] and of the stiffness solve z [1/m], approach [m], a
    material of ``dtype`` arrays (:func:`solver_inputs`); pz [2, wx, wy] the pressure and z,
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

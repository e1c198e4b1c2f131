"""A contact table's grid: where its columns sit along the flat position s, its compression axis
t = sqrt(c / c_max), and the rigid contact onset delta0(s) that the compression c = delta -
delta0(s) is counted from (the parametrisation is described in :mod:`wfjax.contact.tables`)."""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._xla import array_module
from ..params import Flat, Material
from . import geometry3d, kalker
from .interpolation import CENTRE_INNER, CENTRE_OUTER, column_coordinate, column_positions

_DEFAULT_MATERIAL = Material()

# A new flat's columns at s = 0 are 40 times closer than elsewhere (1 + L (1 / CENTRE_INNER -
# 1 / CENTRE_OUTER) = 40), 7.4 more columns on each side: the table then follows direct
# Kalker solves through the cusp at its centre (tests/test_tables.py).
NEW_FLAT_STRETCH = 39.0 / (1.0 / CENTRE_INNER - 1.0 / CENTRE_OUTER)  # m (2 mm)


def column_stretch(kind: str) -> float:
    """The column coordinate's L [m] of a ``kind`` of flat's tables: NEW_FLAT_STRETCH for new
    flats (the cusp at their centre), else 0 (columns uniform in s)."""
    return NEW_FLAT_STRETCH if kind == "new" else 0.0


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
        stretch: the columns' coordinate's L [m]: the columns are uniform in
            :func:`wfjax.contact.interpolation.column_coordinate` (0: in s).
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
    stretch: float = 0.0

    @property
    def x(self) -> np.ndarray:
        """[nx] element centres along x [m]."""
        return (np.arange(self.nx) - (self.nx - 1) / 2) * self.element_size

    @property
    def y(self) -> np.ndarray:
        """[ny] element centres along y [m]."""
        return (np.arange(self.ny) - (self.ny - 1) / 2) * self.element_size

    @property
    def phi_max(self) -> float:
        """The last column's :func:`~wfjax.contact.interpolation.column_coordinate` [m]
        (``s_max`` when the columns are uniform in s)."""
        return float(column_coordinate(self.s_max, self.stretch))

    @property
    def s(self) -> np.ndarray:
        """[n_s] flat positions of the columns [m]."""
        return column_positions(np.linspace(-self.phi_max, self.phi_max, self.n_s),
                                self.stretch)


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
    _, _, d_hertz, _ = geometry3d.elliptic_hertz(max_force, wheel_radius, rail_head_radius,
                                             material)
    c_max = 1.4 * d_hertz if max_compression is None else float(max_compression)
    x, y = geometry3d.contact_grid(flat, wheel_radius, rail_head_radius, material,
                               max_compression=c_max, max_force=max_force, element_size=h)
    half = 0.0 if flat.kind == "none" else flat.half_extent
    # Beyond |s| = half + sqrt(2 R_W c_max) the flat is outside the rigid overlap of every
    # tabulated compression, so the column equals the smooth wheel exactly.
    reach = half + math.sqrt(2 * float(wheel_radius) * c_max) + 2 * h
    stretch = column_stretch(flat.kind)
    n_half = max(1, math.ceil(column_coordinate(reach, stretch) / ds))
    return TableSpec(nx=len(x), ny=len(y), element_size=h,
                     s_max=float(column_positions(n_half * ds, stretch)),
                     n_s=2 * n_half + 1, c_max=c_max, n_t=int(n_t),
                     symmetric=flat.kind in ("new", "rounded", "none"),
                     wheel_radius=float(wheel_radius), rail_head_radius=float(rail_head_radius),
                     stretch=stretch)


def rigid_onset(spec: TableSpec, flat: Flat, s, xp=jnp):
    """Continuum rigid contact onset min_x' gap(x', 0; s) [m] (smooth in s; differentiable).

    The minimum over y is at y = 0 (the flat's transverse arcs follow the rail head), so a 1D
    search suffices: a grid at 1/8 element across the contact grid, refined to 1/256 element
    around its minimiser (the minimiser is held fixed for the gradient: envelope theorem), and
    the chord ends of a new flat (corners of the gap). ``xp``: jnp (traceable) or np (a
    concrete flat's leaves and s; ``s`` may then be [n], the onsets [n]).
    """
    from ..model.geometry import _deviation

    if flat.kind == "sections":
        return _sections_onset(spec, flat, s, xp)
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


def _sections_onset(spec: TableSpec, flat: Flat, s, xp=jnp):
    """:func:`rigid_onset` of a measured 3D flat: min over x' and the grid's lines y of the gap.

    A measured surface need not follow the rail head's arcs, so its least gap may lie off
    y = 0. Each line y of the table grid is searched as :func:`rigid_onset` searches y = 0
    (1/8 element, then 1/256 element around that line's minimiser); the onset is the least of
    the lines.
    """
    from ..model.geometry import _surface
    from ..model.surface import interp_each_row, lateral_rows

    hold = jax.lax.stop_gradient if xp is jnp else np.asarray
    s = xp.asarray(s)[..., None]
    rw, rr = spec.wheel_radius, spec.rail_head_radius
    half = (spec.nx - 1) / 2 * spec.element_size
    step = spec.element_size / 8
    y = spec.y
    arc = rr - np.sqrt(rr**2 - y**2)
    xs = np.arange(-8 * (spec.nx - 1) // 2, 8 * (spec.nx - 1) // 2 + 1) * step
    coarse = (rw - np.sqrt(rw**2 - xs**2))[:, None] + arc + _surface(flat, xs + s, y, rr, xp)
    x0 = hold(xp.asarray(xs)[xp.argmin(coarse, axis=-2)])  # [..., ny] each line's minimiser
    xf = hold(xp.clip(x0[..., None] + np.linspace(-step, step, 65), -half, half))
    rows = lateral_rows(flat.section_y, flat.section_z, y, rr, xp)  # [ny, n]
    r = interp_each_row(rows, flat.profile_x, xf + s[..., None], xp)  # [..., ny, 65]
    gap = rw - xp.sqrt(rw**2 - xf**2) + arc[:, None] + xp.where(r > 0, r, 0.0)
    return xp.min(gap, axis=(-2, -1))


def whole_grid_column(spec: TableSpec, flat: Flat, material: Material, s, tol: float):
    """Forces, stiffnesses and convergence along the t axis for one flat position s
    (every solve on the whole table grid)."""
    x, y = spec.x, spec.y
    h = spec.element_size
    gap = geometry3d.gap_3d(flat, s, x, y, spec.wheel_radius, spec.rail_head_radius)
    onset = rigid_onset(spec, flat, s)
    cfg = kalker._Config(spec.nx, spec.ny, h, h, "fft", tol, 1000)

    def step(carry, c):
        p_prev, z_prev = carry
        r, z = kalker._solve_impl(cfg, gap, material, onset + c, None, p_prev, 50, True, False,
                                  z_init=z_prev)
        return (r.pressure, z), (r.force, r.stiffness, r.diagnostics.converged)

    p0 = jnp.zeros((spec.nx, spec.ny), gap.dtype)
    _, (f, k, ok) = jax.lax.scan(step, (p0, p0), jnp.asarray(compression_nodes(spec)))
    return (onset,) + column_outputs(spec, f, k) + (jnp.all(ok),)


def compression_nodes(spec: TableSpec) -> np.ndarray:
    """[n_t - 1] compressions c_j = c_max t_j^2 of the solved t nodes (t_0 = 0 is F = 0)."""
    return spec.c_max * np.linspace(0.0, 1.0, spec.n_t)[1:] ** 2


def column_outputs(spec: TableSpec, f, k):
    """Node forces and slopes dF/du [..., n_t] from the solved forces f and stiffnesses k
    [..., n_t - 1]."""
    xp = array_module(f)
    t = np.linspace(0.0, 1.0, spec.n_t)[1:]
    zero = xp.zeros(f.shape[:-1] + (1,), f.dtype)
    return (xp.concatenate([zero, f], axis=-1),
            xp.concatenate([zero, k * 2 * spec.c_max * t / (spec.n_t - 1)], axis=-1))

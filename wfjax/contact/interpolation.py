"""Evaluating a contact table: F3D(delta, s) by cubic Hermite interpolation in the compression
coordinate t = sqrt(c / c_max) and Catmull-Rom interpolation across the s columns (the scheme is
described in :mod:`wfjax.contact.tables`, which builds the tables)."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np


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
        stretch: L [m] of the column coordinate :func:`column_coordinate` (0: columns
            uniform in s; a new flat's tables crowd their columns at its centre). ``s_min``
            and ``ds`` are in that coordinate.
    """

    s_min: Any
    ds: Any
    c_max: Any
    onset: Any
    force: Any
    slope: Any
    converged: Any
    stretch: Any = 0.0


# A new flat's force at a fixed compression has a cusp at its centre s = 0 (the chord lies
# parallel to the rail there), narrower than a contact element (about 0.2 mm at 25 um
# compression); its tables crowd their columns there, uniform within CENTRE_INNER and
# beyond CENTRE_OUTER (docs/convergence.md, "Min force").
CENTRE_INNER = 5e-5  # m
CENTRE_OUTER = 2e-3  # m


def column_coordinate(s, stretch):
    """The columns' coordinate phi(s) [m] at flat position ``s`` [m]: odd, smooth and
    increasing, s + L (asinh(s / CENTRE_INNER) - asinh(s / CENTRE_OUTER)) with L =
    ``stretch`` [m]; columns uniform in phi are 1 + L (1 / CENTRE_INNER - 1 / CENTRE_OUTER)
    times closer at s = 0 than far from it, where phi - s tends to L ln(CENTRE_OUTER /
    CENTRE_INNER). numpy in, numpy out; jax.numpy otherwise."""
    xp = jnp if isinstance(s, jax.Array) or isinstance(stretch, jax.Array) else np
    return s + stretch * (xp.arcsinh(s / CENTRE_INNER) - xp.arcsinh(s / CENTRE_OUTER))


def column_positions(phi, stretch):
    """The flat positions s [m] with :func:`column_coordinate` ``phi`` [m], any shape
    (bisection to rounding: phi >= |s| on the same side). numpy in, numpy out; jax.numpy
    for traced ``phi`` (a ``fori_loop``)."""
    traced = isinstance(phi, jax.Array) or isinstance(stretch, jax.Array)
    xp = jnp if traced else np
    target = xp.abs(xp.asarray(phi, dtype=float))

    def halve(_, bounds):
        lo, hi = bounds
        mid = 0.5 * (lo + hi)
        low = column_coordinate(mid, stretch) < target
        return xp.where(low, mid, lo), xp.where(low, hi, mid)

    bounds = (xp.zeros_like(target), target)
    if traced:
        bounds = jax.lax.fori_loop(0, 64, halve, bounds)
    else:
        for k in range(64):
            bounds = halve(k, bounds)
    return xp.sign(phi) * 0.5 * (bounds[0] + bounds[1])


def pad_columns(table: ContactTable, n_s: int) -> ContactTable:
    """``table`` widened to ``n_s`` columns by repeating its end columns (half on either side;
    its column coordinate, :func:`column_coordinate`, extends by whole spacings).

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
    u = jnp.clip((column_coordinate(s, table.stretch) - table.s_min) / table.ds, 0.0,
                 n_s - 1.0)
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

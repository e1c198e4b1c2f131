"""A measured 3D flat's surface: radial deviation records at a few lateral positions, interpolated
across the width by a natural cubic spline and along the circumference linearly.

Conventions (those of :mod:`wfjax.model.geometry`): ``x`` circumferential from the flat centre,
``y`` transverse from the running band centre (the nominal contact line), both in m; the records
hold the deviation S_j(x_i) [m] at lateral positions y_j, positive where material is missing
(signed: a measured record dips below zero between the flat and its ends).

The surface (:func:`sections_surface`):

* across the width, S(x_i, y) is the natural cubic spline through (y_j, S_j(x_i)) for each
  record node x_i: C2 in y, exact at the measured lines, zero curvature at the band's edges
  (it invents no slope there). It is the cubic B-spline interpolant with knots at the lines,
  the tensor-product B-spline surface of the literature, reduced to linear in x;
* along the circumference, linear between the record nodes (the interpolation of a measured
  profile, :meth:`wfjax.params.Flat.from_profile`; the records come at 1 mm, the contact
  elements' size), zero outside the records' support;
* outside the measured band the edge record continues as the rail head's arc cuts it, the rule
  of the ideal flats: S(x, y) = S(x, y_e) - (a(y) - a(y_e)), a(y) = R_R - sqrt(R_R^2 - y^2),
  y_e the nearer edge (continuous at the edge);
* the flat removes material only: r(x, y) = max(0, S(x, y)), clipped after the interpolation
  (so a flat's edge falls where the interpolated surface crosses zero, not at a node).

The spline is linear in the record values, so every evaluation is a fixed weight matrix times
the values: gradients reach each record value.
"""

from __future__ import annotations

import numpy as np

__all__ = ["spline_weights", "lateral_rows", "interp_rows", "interp_each_row",
           "sections_surface", "centre_line"]


def spline_weights(nodes, query, xp=np):
    """Weights W [nq, n] of the natural cubic spline through ``n`` lateral ``nodes`` [m].

    S(query) = W @ values for values at the nodes. ``query`` [nq] [m] is clipped to the nodes'
    range. Two nodes give linear interpolation. Exact at the nodes (W is a unit row there).
    """
    y = xp.asarray(nodes, dtype=float)
    q = xp.clip(xp.asarray(query, dtype=float), y[0], y[-1])
    n = y.shape[0]
    h = y[1:] - y[:-1]
    eye = xp.eye(n)
    if n > 2:
        # Interior rows: h_{i-1} M_{i-1} + 2 (h_{i-1} + h_i) M_i + h_i M_{i+1}
        #               = 6 ((v_{i+1} - v_i) / h_i - (v_i - v_{i-1}) / h_{i-1}); M_0 = M_{n-1} = 0.
        a = (xp.diag(2 * (h[:-1] + h[1:])) + xp.diag(h[1:-1], 1) + xp.diag(h[1:-1], -1))
        d = 6 * ((eye[2:] - eye[1:-1]) / h[1:, None] - (eye[1:-1] - eye[:-2]) / h[:-1, None])
        g = xp.linalg.solve(a, d)
        zero = xp.zeros((1, n))
        g = xp.concatenate([zero, g, zero], axis=0)  # [n, n]: M = g @ v
    else:
        g = xp.zeros((n, n))
    k = xp.clip(xp.searchsorted(y, q, side="right") - 1, 0, n - 2)
    hk = h[k][:, None]
    b = ((q - y[k]) / h[k])[:, None]
    a1 = 1.0 - b
    return (a1 * eye[k] + b * eye[k + 1]
            + ((a1**3 - a1) * g[k] + (b**3 - b) * g[k + 1]) * hk**2 / 6.0)


def lateral_rows(section_y, section_z, y, rail_head_radius, xp=np):
    """Unclipped surface S(x_i, y) [ny, nx] at the record nodes x_i for lateral ``y`` [ny] [m].

    Inside the band the natural spline of the records; outside, the nearer edge record lowered
    by the rail head's arc (module docstring). ``section_z`` [n_lines, nx] [m].
    """
    yn = xp.asarray(section_y, dtype=float)
    y = xp.asarray(y, dtype=float)
    w = spline_weights(yn, y, xp)
    yc = xp.clip(y, yn[0], yn[-1])
    r = rail_head_radius
    drop = (r - xp.sqrt(r**2 - y**2)) - (r - xp.sqrt(r**2 - yc**2))
    return w @ xp.asarray(section_z) - drop[:, None]


def interp_rows(rows, section_x, x, xp=np):
    """Linear interpolation along x of each row: ``rows`` [ny, nx] at nodes ``section_x`` [nx],
    read at ``x`` [...] [m]; zero outside the nodes' support. Returns [..., ny]."""
    sx = xp.asarray(section_x, dtype=float)
    x = xp.asarray(x, dtype=float)
    n = sx.shape[0]
    k = xp.clip(xp.searchsorted(sx, x, side="right") - 1, 0, n - 2)
    t = (x - sx[k]) / (sx[k + 1] - sx[k])
    inside = (x >= sx[0]) & (x <= sx[-1])
    lo, hi = rows[:, k], rows[:, k + 1]  # [ny, ...]
    val = xp.where(inside, lo * (1.0 - t) + hi * t, 0.0)
    return xp.moveaxis(val, 0, -1)


def interp_each_row(rows, section_x, x, xp=np):
    """Row j of ``rows`` [ny, nx] read at its own positions ``x[..., j, :]`` [..., ny, m] [m]
    (linear, zero outside the support). Returns [..., ny, m]."""
    sx = xp.asarray(section_x, dtype=float)
    n = sx.shape[0]
    k = xp.clip(xp.searchsorted(sx, x, side="right") - 1, 0, n - 2)
    t = (x - sx[k]) / (sx[k + 1] - sx[k])
    j = np.arange(rows.shape[0])[:, None]
    val = rows[j, k] * (1.0 - t) + rows[j, k + 1] * t
    return xp.where((x >= sx[0]) & (x <= sx[-1]), val, 0.0)


def sections_surface(section_x, section_y, section_z, x, y, rail_head_radius, xp=np):
    """The measured flat's deviation r(x, y) = max(0, S(x, y)) [m] on a grid.

    Args:
        section_x: [nx] record nodes along the circumference [m], strictly increasing.
        section_y: [n_lines] lateral positions of the records [m], strictly increasing.
        section_z: [n_lines, nx] signed deviation of the records [m].
        x: [..., nq] circumferential positions [m]; y: [ny] lateral positions [m].
        rail_head_radius: R_R [m] (the rule outside the measured band).
        xp: array module (np for concrete builds, jnp traced).

    Returns:
        [..., nq, ny] deviation [m], >= 0.
    """
    rows = lateral_rows(section_y, section_z, xp.atleast_1d(xp.asarray(y, dtype=float)),
                        rail_head_radius, xp)
    s = interp_rows(rows, section_x, x, xp)
    return xp.where(s > 0, s, 0.0)


def centre_line(section_x, section_y, section_z, x, xp=np):
    """The surface on the nominal contact line y = 0: max(0, S(x, 0)) [m], shaped like ``x``.

    The 2D bedding and the Hertz models see the measured flat through this line (y = 0 lies
    in the measured band: :meth:`wfjax.params.Flat.from_sections` checks it).
    """
    rows = spline_weights(section_y, xp.zeros(1), xp) @ xp.asarray(section_z)
    s = interp_rows(rows, section_x, x, xp)[..., 0]
    return xp.where(s > 0, s, 0.0)

"""The track's finite-element matrices: Friedman & Kosmatka (1993) two-node Rayleigh-Timoshenko
rail elements, rail pads, half-sleeper masses and ballast assembled on the free DOFs (the model
is described in :mod:`wfjax.model.track`), and the static solve on them."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.csgraph
import scipy.sparse.linalg

from ..fields import concrete_positive_numbers
from ..params import SUPPORT_FIELDS, Track
from .sleepers import is_uniform, support_arrays

_RAIL_FIELDS = (
    "bending_stiffness", "shear_stiffness", "rail_mass", "rail_rotary_inertia",
    "sleeper_spacing",
)


# --------------------------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------------------------
def track_numbers(track: Track) -> dict[str, float | np.ndarray]:
    """Rail numbers (floats) and supports: a float per field when every sleeper has the same
    value (the uniform track: exactly today's numbers and cache keys), else the whole
    per-sleeper array [n_bays - 1] of every support field."""
    if not isinstance(track, Track):
        raise ValueError(f"track must be a wfjax.Track, got {type(track).__name__}")
    out: dict[str, float | np.ndarray] = dict(concrete_positive_numbers(track, _RAIL_FIELDS))
    arrays = support_arrays(track)
    uniform = is_uniform(track)
    for name in SUPPORT_FIELDS:
        if name == "ballast_gap" and not np.any(arrays[name]):
            continue  # no hanging sleeper: the numbers and cache keys of before
        out[name] = float(arrays[name][0]) if uniform else arrays[name]
    for name, low in (("n_bays", 4), ("elements_per_bay", 1)):
        value = getattr(track, name)
        if not isinstance(value, (int, np.integer)) or value < low:
            raise ValueError(f"Track.{name} must be an integer >= {low}, got {value!r}")
    return out


# --------------------------------------------------------------------------------------------
# finite-element model
# --------------------------------------------------------------------------------------------
class FEModel(NamedTuple):
    """Assembled FE matrices of the track (scipy CSC, free DOFs only).

    DOF order: rail nodes 1 .. N-1 as (w, theta) pairs, then the interior sleepers.
    """

    stiffness: scipy.sparse.csc_matrix  # [n_dof, n_dof] N/m
    mass: scipy.sparse.csc_matrix       # [n_dof, n_dof] kg
    damping: scipy.sparse.csc_matrix    # [n_dof, n_dof] N s/m
    node_x: np.ndarray                  # [N+1] rail node positions [m] (including clamped ends)
    element_length: float               # [m]
    phi: float                          # shear parameter 12 EI / (kGA Le^2)
    n_rail_dof: int                     # 2 (N - 1)


def element_matrices(bending_stiffness, shear_stiffness, rail_mass, rotary_inertia, length):
    """Friedman & Kosmatka (1993) Timoshenko element: stiffness and consistent mass [4x4].

    DOFs (w1, theta1, w2, theta2); units N/m, N, N m/rad and kg, kg m, kg m^2.
    Returns ``(K, M, phi)`` with ``M = M_t + M_r`` (translational + rotary inertia).
    """
    ei, L = bending_stiffness, length
    phi = 12.0 * ei / (shear_stiffness * L**2)
    k = ei / ((1 + phi) * L**3) * np.array([
        [12, 6 * L, -12, 6 * L],
        [6 * L, (4 + phi) * L**2, -6 * L, (2 - phi) * L**2],
        [-12, -6 * L, 12, -6 * L],
        [6 * L, (2 - phi) * L**2, -6 * L, (4 + phi) * L**2]])
    m11 = 70 * phi**2 + 147 * phi + 78
    m12 = (35 * phi**2 + 77 * phi + 44) * L / 4
    m13 = 35 * phi**2 + 63 * phi + 27
    m14 = -(35 * phi**2 + 63 * phi + 26) * L / 4
    m22 = (7 * phi**2 + 14 * phi + 8) * L**2 / 4
    m24 = -(7 * phi**2 + 14 * phi + 6) * L**2 / 4
    mt = rail_mass * L / (210 * (1 + phi) ** 2) * np.array([
        [m11, m12, m13, m14],
        [m12, m22, -m14, m24],
        [m13, -m14, m11, -m12],
        [m14, m24, -m12, m22]])
    r12 = -(15 * phi - 3) * L
    r22 = (10 * phi**2 + 5 * phi + 4) * L**2
    r24 = (5 * phi**2 - 5 * phi - 1) * L**2
    mr = rotary_inertia / (30 * (1 + phi) ** 2 * L) * np.array([
        [36, r12, -36, r12],
        [r12, r22, -r12, r24],
        [-36, -r12, 36, -r12],
        [r12, r24, -r12, r22]])
    return k, mt + mr, phi


def shape_functions(xi, phi, length):
    """Timoshenko displacement shape functions N1..N4 at xi = s / Le in [0, 1] (array-like).

    Returns a tuple of four arrays shaped like ``xi`` (N2, N4 in m/rad). Works with numpy and
    jax.numpy inputs.
    """
    xp = jnp if isinstance(xi, jax.Array) else np
    xi = xp.asarray(xi)
    d = 1.0 + phi
    n1 = (2 * xi**3 - 3 * xi**2 - phi * xi + 1 + phi) / d
    n2 = length * (xi**3 - (2 + phi / 2) * xi**2 + (1 + phi / 2) * xi) / d
    n3 = -(2 * xi**3 - 3 * xi**2 - phi * xi) / d
    n4 = length * (xi**3 - (1 - phi / 2) * xi**2 - (phi / 2) * xi) / d
    return n1, n2, n3, n4


END_GRADING = 8.0  # the outermost absorbing sleeper's damping over the track's


def end_grading(n_sleepers: int, n_absorbing: int) -> np.ndarray:
    """[n_sleepers] factors on the sleepers' pad and ballast damping: 1 inside, and over the
    last ``n_absorbing`` at each end END_GRADING^(i / n_absorbing), i = 1 .. n_absorbing
    outwards (3 sleepers: 2, 4, 8). A gentle grading absorbs the waves the clamped ends
    would reflect; an abrupt one reflects them itself (x3, 10, 30 kept a 20 km/h min force
    0.65 kN off a 50-bay track's, x2, 4, 8 within 0.01 kN; docs/convergence.md)."""
    if 2 * n_absorbing > n_sleepers:  # checked here, on the track as lengthened
        raise ValueError(f"Track.absorbing_sleepers = {n_absorbing} needs at least "
                         f"{2 * n_absorbing} sleepers ({2 * n_absorbing + 1} bays), the track "
                         f"has {n_sleepers}: give more bays or fewer absorbing sleepers")
    g = np.ones(n_sleepers)
    if n_absorbing:
        ramp = END_GRADING ** (np.arange(1, n_absorbing + 1) / n_absorbing)
        g[:n_absorbing], g[n_sleepers - n_absorbing:] = ramp[::-1], ramp
    return g


END_RAIL_DAMPING = 3000.0  # 1/s: the rail's mass-proportional damping at the track's ends


def end_rail_damping(element_x, track_length: float, zone: float) -> np.ndarray:
    """[n_el] mass-proportional damping [1/s] of the rail elements centred at ``element_x``
    [m from the left end] of a rail ``track_length`` [m] long: END_RAIL_DAMPING ((zone - d) /
    zone)^2 within ``zone`` [m] of the nearer end (d [m] from it), 0 elsewhere.

    Near the pinned-pinned frequency the rail's waves hardly move the sleepers, so the
    sleepers' graded damping (:func:`end_grading`) cannot absorb them; damping the rail itself
    over the absorbing zone does (24 against 70 bays, new flat, 20 km/h, 3D: min force 0.73 ->
    0.38 kN apart; 1,000 and 10,000 1/s did less; docs/convergence.md, "Absorbing ends")."""
    x = np.asarray(element_x, dtype=float)
    d = np.minimum(x, track_length - x)
    return END_RAIL_DAMPING * np.clip((zone - d) / zone, 0.0, 1.0) ** 2


def assemble(track: Track) -> FEModel:
    """Assemble the sparse stiffness, mass and damping matrices of the track FE model.

    Per-sleeper supports (arrays ``[n_bays - 1]`` in the track's support fields, see
    :mod:`wfjax.model.supports`) enter sleeper by sleeper; scalars are the same at every sleeper.
    A hanging sleeper (``ballast_gap > 0``) has no ballast here: its one-sided ballast is a
    non-linear force solved in the time loop (:func:`wfjax.model.supports.one_sided_spec`).
    The last ``track.absorbing_sleepers`` sleepers at each end have their pad and ballast
    damping graded up (:func:`end_grading`), and the rail over the same zone ((n + 1) bays at
    each end) a mass-proportional damping (:func:`end_rail_damping`).
    """
    p = track_numbers(track)
    nb, ne = int(track.n_bays), int(track.elements_per_bay)
    n_el = nb * ne
    le = p["sleeper_spacing"] / ne
    ke, me, phi = element_matrices(p["bending_stiffness"], p["shear_stiffness"],
                                   p["rail_mass"], p["rail_rotary_inertia"], le)
    n_rail = 2 * (n_el - 1)
    n_sl = nb - 1
    n_dof = n_rail + n_sl

    # global (unconstrained) rail dof g = 2*node + {0, 1}; free rail dof = g - 2
    e = np.arange(n_el)
    gdof = np.stack([2 * e, 2 * e + 1, 2 * e + 2, 2 * e + 3], axis=1) - 2  # [n_el, 4]
    rows = np.repeat(gdof, 4, axis=1).ravel()
    cols = np.tile(gdof, (1, 4)).ravel()
    ok = (rows >= 0) & (rows < n_rail) & (cols >= 0) & (cols < n_rail)
    kv = np.tile(ke.ravel(), n_el)[ok]
    mv = np.tile(me.ravel(), n_el)[ok]
    rows, cols = rows[ok], cols[ok]

    # supports: rail w dof of node j*ne (j = 1..nb-1) <-> sleeper dof n_rail + j - 1
    j = np.arange(1, nb)
    rw = 2 * (j * ne) - 2
    sl = n_rail + j - 1
    s_rows = np.concatenate([rw, sl, rw, sl])
    s_cols = np.concatenate([rw, sl, sl, rw])
    ones = np.ones(n_sl)
    kp, kb, cp, cb, msl = (p[n] * ones for n in ("pad_stiffness", "ballast_stiffness",
                                                  "pad_damping", "ballast_damping",
                                                  "sleeper_mass"))
    hanging = p.get("ballast_gap", 0.0) * ones > 0  # one-sided: the linear model is open there
    grading = end_grading(n_sl, int(track.absorbing_sleepers))
    kb, cb = np.where(hanging, 0.0, kb), np.where(hanging, 0.0, cb * grading)
    cp = cp * grading
    ks_v = np.concatenate([kp, kp + kb, -kp, -kp])
    cs_v = np.concatenate([cp, cp + cb, -cp, -cp])

    shape = (n_dof, n_dof)
    k = scipy.sparse.coo_matrix((np.concatenate([kv, ks_v]),
                                 (np.concatenate([rows, s_rows]), np.concatenate([cols, s_cols]))),
                                shape=shape).tocsc()
    m = scipy.sparse.coo_matrix((np.concatenate([mv, msl]),
                                 (np.concatenate([rows, sl]), np.concatenate([cols, sl]))),
                                shape=shape).tocsc()
    n_abs = int(track.absorbing_sleepers)
    eta = (end_rail_damping((e + 0.5) * le, n_el * le, (n_abs + 1) * p["sleeper_spacing"])
           if n_abs else np.zeros(n_el))  # [n_el] 1/s
    cv = np.repeat(eta, 16)[ok] * mv  # eta of each element times its mass entries
    c = scipy.sparse.coo_matrix((np.concatenate([cs_v, cv]),
                                 (np.concatenate([s_rows, rows]), np.concatenate([s_cols, cols]))),
                                shape=shape).tocsc()
    node_x = (np.arange(n_el + 1) * le) - (nb // 2) * p["sleeper_spacing"]
    return FEModel(k, m, c, node_x, le, phi, n_rail)


NODE_SNAP = 1e-9  # a coordinate within this fraction of an element of a node lies on it


def fraction_in_element(s, element_length: float) -> np.ndarray:
    """Position of coordinates ``s`` [m] (measured from a node) within their elements, in
    [0, 1); 0 on a node (to :data:`NODE_SNAP`)."""
    xi = np.mod(np.asarray(s, dtype=float) / element_length, 1.0)
    return np.where(np.minimum(xi, 1 - xi) < NODE_SNAP, 0.0, xi)


def element_shapes(s, element_length: float, n_elements: int, phi: float):
    """(element index [n], shape functions [4, n]) of unit forces at coordinates ``s`` [m],
    [n], measured from the first node of ``n_elements`` elements; the element's dofs are
    2 e .. 2 e + 3 counting the first node's from 0. A coordinate on a node goes to the
    element it starts (the last node to the last element)."""
    s = np.asarray(s, dtype=float)
    e = np.clip(np.floor(s / element_length + NODE_SNAP).astype(int), 0, n_elements - 1)
    xi = (s - e * element_length) / element_length
    return e, np.stack(shape_functions(xi, phi, element_length), axis=0)


def load_vector(fe: FEModel, x) -> scipy.sparse.csc_matrix:
    """[n_dof, n_x] sparse matrix whose columns are the nodal loads of unit forces at ``x``."""
    x = np.atleast_1d(np.asarray(x, dtype=float))
    lo, hi = fe.node_x[0], fe.node_x[-1]
    if not np.all(np.isfinite(x)) or np.any(x < lo) or np.any(x > hi):
        raise ValueError(f"x must be finite and within the rail [{lo:g}, {hi:g}] m, got {x!r}")
    e, n = element_shapes(x - lo, fe.element_length, fe.node_x.size - 1, fe.phi)
    g = np.stack([2 * e, 2 * e + 1, 2 * e + 2, 2 * e + 3], axis=0) - 2  # clamped first node
    ok = (g >= 0) & (g < fe.n_rail_dof)
    cols = np.broadcast_to(np.arange(x.size), g.shape)
    return scipy.sparse.csc_matrix((n[ok], (g[ok], cols[ok])),
                                   shape=(fe.stiffness.shape[0], x.size))


# --------------------------------------------------------------------------------------------
# direct solves
# --------------------------------------------------------------------------------------------
def static_solve(fe: FEModel, rhs) -> np.ndarray:
    """K^-1 rhs [m], dense [n_dof, k], for loads ``rhs`` [n_dof, k] [N] (dense or sparse) by a
    dense Cholesky factor of K. With more right-hand sides than DOFs (a whole-rail table:
    2241 x n four-entry load vectors, where SuperLU's sparse solve took 7 s) through K^-1 and
    the sparse product (K is symmetric); with a few, a solve (about the factorisation's cost)."""
    factor = scipy.linalg.cho_factor(fe.stiffness.toarray())
    n_dof = fe.stiffness.shape[0]
    if rhs.shape[1] > n_dof:
        return np.asarray(rhs.T @ scipy.linalg.cho_solve(factor, np.eye(n_dof))).T
    dense = rhs.toarray() if scipy.sparse.issparse(rhs) else np.asarray(rhs, dtype=float)
    return scipy.linalg.cho_solve(factor, dense)


def element_interior_compliance(track: Track, xi) -> np.ndarray:
    """Static compliance [m/N] that the element's shape functions miss at a point load inside
    an element: the deflection under a unit load at fraction ``xi`` [any shape] of an element
    clamped at both its nodes (0 at the nodes).

    The Timoshenko element is exact for loads at its nodes only; a load inside it is spread
    to the nodes by the shape functions, which cannot follow the kink of the exact deflection
    under the load (mostly shear: about ``L / (4 kGA)`` at the middle, 8e-11 m/N for 8
    elements of 0.65 m). The exact deflection is the FE one plus this clamped-clamped
    part (superposition), computed exactly with a node at the load: two Timoshenko elements
    of lengths ``xi L`` and ``(1 - xi) L``.
    """
    p = track_numbers(track)
    ei, kga = float(p["bending_stiffness"]), float(p["shear_stiffness"])
    le = float(p["sleeper_spacing"]) / int(track.elements_per_bay)
    xi = np.asarray(xi, dtype=float)
    out = np.zeros(xi.shape)
    for i, x in np.ndenumerate(xi):
        if 1e-9 < x < 1 - 1e-9:
            ka = element_matrices(ei, kga, 1.0, 1.0, x * le)[0]
            kb = element_matrices(ei, kga, 1.0, 1.0, (1 - x) * le)[0]
            out[i] = np.linalg.inv(ka[2:, 2:] + kb[:2, :2])[0, 0]
    return out

"""Discretely supported track: the Nielsen-Igeland finite-element model (Section 3.2, Table 2).

Model (Nielsen & Igeland 1995, J. Sound Vib. 187, 825-839): a 60E1 rail of ``track.n_bays``
sleeper bays of length L_S, discretised by ``track.elements_per_bay`` two-node
Rayleigh-Timoshenko beam elements per bay (shear deformation and rotary inertia) with the
element matrices of **Friedman & Kosmatka (1993)**, "An improved two-node Timoshenko beam
finite element", Computers & Structures 47, 473-481 (exact static shape functions,
consistent translational + rotary mass; written out in ``reference/formulas.md``). Below every
interior sleeper position the rail node is joined by a rail pad (k_P || c_P) to a half-sleeper
mass m_SL, which rests on ballast (k_B || c_B) on rigid ground. Both rail ends are clamped
(displacement and rotation zero); the end sleepers under the clamps carry no load and are left
out. The rail itself is undamped, so the damping is non-proportional.

Coordinates: ``x`` [m] along the rail, ``x = 0`` at the sleeper centre in the middle of the
track (sleeper number ``n_bays // 2``), so sleepers sit at ``x = j L_S`` and midspans at
``x = (j + 1/2) L_S``. Displacements are positive in the direction of the applied force.

Main entry points:

* :func:`receptance` -- point / transfer receptance by a direct sparse frequency-domain solve
  (the reference).
* :func:`modal_model` -> :class:`ModalModel` -- complex modes with a static correction for the
  truncated modes; what the time loop uses (cached on disk, speed independent).
* :func:`moving_greens` -- moving Green's functions g(x0, t) (Eq. 5) from the modal model;
  :func:`moving_greens_newmark` computes the same by direct time integration of the full FE
  model (independent check).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.csgraph
import scipy.sparse.linalg

from .. import _cache
from .._xla import to_device
from ..params import SUPPORT_FIELDS, Track, concrete_positive_numbers
from .modal import complex_modes, discrete_step_coefficients, real_times_complex
from .sleepers import is_mirror_symmetric, is_uniform, support_arrays

__all__ = [
    "ModalModel",
    "MovingGreens",
    "FEModel",
    "assemble",
    "receptance",
    "static_deflection",
    "modal_model",
    "mode_shapes_at",
    "interpolate_nodal",
    "residual_compliance_at",
    "modal_receptance",
    "modal_sum",
    "moving_greens",
    "moving_greens_newmark",
    "discrete_step_coefficients",
]

_RAIL_FIELDS = (
    "bending_stiffness", "shear_stiffness", "rail_mass", "rail_rotary_inertia",
    "sleeper_spacing",
)


# --------------------------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------------------------
def _track_numbers(track: Track) -> dict[str, float | np.ndarray]:
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


def _check_freqs(freqs) -> np.ndarray:
    f = np.asarray(freqs, dtype=float)
    if f.ndim > 1 or f.size == 0 or not np.all(np.isfinite(f)) or np.any(f < 0):
        raise ValueError(f"freqs must be a non-empty 1-D array of finite frequencies >= 0 Hz, "
                         f"got {freqs!r}")
    return np.atleast_1d(f)


def _check_positive_scalar(name: str, value, unit: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a number > 0 {unit}, got {value!r}") from exc
    if not math.isfinite(v) or v <= 0:
        raise ValueError(f"{name} must be finite and > 0 {unit}, got {value!r} "
                         f"(allowed range: (0, inf) {unit})")
    return v


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


def assemble(track: Track) -> FEModel:
    """Assemble the sparse stiffness, mass and damping matrices of the track FE model.

    Per-sleeper supports (arrays ``[n_bays - 1]`` in the track's support fields, see
    :mod:`wfjax.model.supports`) enter sleeper by sleeper; scalars are the same at every sleeper.
    A hanging sleeper (``ballast_gap > 0``) has no ballast here: its one-sided ballast is a
    non-linear force solved in the time loop (:func:`wfjax.model.supports.one_sided_spec`).
    """
    p = _track_numbers(track)
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
    kb, cb = np.where(hanging, 0.0, kb), np.where(hanging, 0.0, cb)
    ks_v = np.concatenate([kp, kp + kb, -kp, -kp])
    cs_v = np.concatenate([cp, cp + cb, -cp, -cp])

    shape = (n_dof, n_dof)
    k = scipy.sparse.coo_matrix((np.concatenate([kv, ks_v]),
                                 (np.concatenate([rows, s_rows]), np.concatenate([cols, s_cols]))),
                                shape=shape).tocsc()
    m = scipy.sparse.coo_matrix((np.concatenate([mv, msl]),
                                 (np.concatenate([rows, sl]), np.concatenate([cols, sl]))),
                                shape=shape).tocsc()
    c = scipy.sparse.coo_matrix((cs_v, (s_rows, s_cols)), shape=shape).tocsc()
    node_x = (np.arange(n_el + 1) * le) - (nb // 2) * p["sleeper_spacing"]
    return FEModel(k, m, c, node_x, le, phi, n_rail)


def _load_vector(fe: FEModel, x) -> scipy.sparse.csc_matrix:
    """[n_dof, n_x] sparse matrix whose columns are the nodal loads of unit forces at ``x``."""
    x = np.atleast_1d(np.asarray(x, dtype=float))
    lo, hi = fe.node_x[0], fe.node_x[-1]
    if not np.all(np.isfinite(x)) or np.any(x < lo) or np.any(x > hi):
        raise ValueError(f"x must be finite and within the rail [{lo:g}, {hi:g}] m, got {x!r}")
    n_el = fe.node_x.size - 1
    e = np.clip(np.floor((x - lo) / fe.element_length).astype(int), 0, n_el - 1)
    xi = (x - fe.node_x[e]) / fe.element_length
    n = np.stack(shape_functions(xi, fe.phi, fe.element_length), axis=0)  # [4, n_x]
    g = np.stack([2 * e, 2 * e + 1, 2 * e + 2, 2 * e + 3], axis=0) - 2
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


def receptance(track: Track, freqs, x: float = 0.0, x_response=None) -> np.ndarray:
    """Rail receptance [m/N] by a direct sparse frequency-domain solve of the FE model.

    Args:
        track: the track parameters.
        freqs: [n_f] frequencies [Hz] (>= 0).
        x: excitation position [m] (0 = above the middle sleeper, L_S/2 = midspan).
        x_response: response position(s) [m], scalar or [n_r]; default ``x`` (point receptance).

    Returns:
        complex [n_f] (scalar ``x_response``) or [n_f, n_r]: displacement at ``x_response``
        per unit harmonic force at ``x`` (convention exp(i omega t)).
    """
    f = _check_freqs(freqs)
    fe = assemble(track)
    scalar = x_response is None or np.ndim(x_response) == 0
    xr = x if x_response is None else x_response
    b = _load_vector(fe, x).toarray()[:, 0]
    nr = _load_vector(fe, xr)  # [n_dof, n_r]
    out = np.empty((f.size, nr.shape[1]), dtype=complex)
    k, m, c = fe.stiffness, fe.mass, fe.damping
    for i, fi in enumerate(f):
        w = 2 * np.pi * fi
        d = (k - w**2 * m + 1j * w * c).tocsc()
        u = scipy.sparse.linalg.spsolve(d, b.astype(complex))
        out[i] = nr.T @ u
    return out[:, 0] if scalar else out


def static_deflection(track: Track, force: float = 118e3, x: float = 0.0) -> float:
    """Static rail deflection [m] at ``x`` [m] under a point force ``force`` [N] at ``x``."""
    force = _check_positive_scalar("force", force, "N")
    return float(np.real(receptance(track, [0.0], x)[0])) * force


# --------------------------------------------------------------------------------------------
# modal model
# --------------------------------------------------------------------------------------------
class ModalModel(NamedTuple):
    """Complex-mode model of a linear structure with a static correction (a JAX pytree).

    Rail displacement at ``x`` due to a unit impulse at ``x0`` at t = 0 (units m/(N s)),
    for ``t > 0``::

        h(x, x0, t) = Re sum_r weights_r * phi_r(x) * phi_r(x0) * exp(poles_r t)

    plus, for a point load, the instantaneous static contribution of the truncated modes
    ``residual_compliance_at(model, x) * F(t)`` [m] (a delta function in h).

    Fields:
        poles: complex [n_modes] lambda_r [rad/s]; one representative (Im > 0) per conjugate
            pair plus real poles.
        weights: float [n_modes]: 2.0 for pair representatives, 1.0 for real poles.
        node_x: float [n_nodes] rail node positions [m], x = 0 at the middle sleeper.
        shapes: complex [n_modes, n_nodes, 2] (displacement [sqrt(1/kg)-like units such that
            phi*phi has m/(N s)], rotation per m of that) at the nodes; clamped ends are 0.
        residual_x: float [n_res] positions [m] of the residual table: across one bay
            [0, L_S] for a uniform track (periodic in the bay); along the whole rail (absolute
            coordinates, ``n_residual - 1`` intervals per bay) when the supports vary.
        residual: float [n_res] static compliance [m/N] of the truncated modes at (x, x):
            K^-1(x, x) - sum_kept Re(w phi^2 / (-lambda)).
        sleeper_spacing: L_S [m].
        element_phi: Timoshenko shear parameter 12 EI/(kGA Le^2) of the rail elements (needed
            by the shape functions in :func:`mode_shapes_at`).
        sleeper_shapes: complex [n_modes, n_bays - 1] the same modes' sleeper displacements
            (interior sleepers, left to right; sleeper ``i`` sits at ``(i + 1 - n_bays // 2)
            L_S``), read by the sensors (:mod:`wfjax.scenario.sensors`).
    """

    poles: jax.Array
    weights: jax.Array
    node_x: jax.Array
    shapes: jax.Array
    residual_x: jax.Array
    residual: jax.Array
    sleeper_spacing: float
    element_phi: float = 0.0
    sleeper_shapes: jax.Array | None = None


def mode_shapes_at(model: ModalModel, x) -> jax.Array:
    """phi_r(x): mode shapes at rail positions ``x`` [m] (any shape), complex [..., n_modes].

    Interpolates with the Timoshenko shape functions of the element containing ``x`` (the FE
    model's own interpolation). Positions outside the rail are clamped to its ends. Pure
    ``jax.numpy``; jit/vmap/grad-able in ``x``.
    """
    x = jnp.asarray(x, dtype=jnp.result_type(x, float))  # float32 stays float32
    node_x = model.node_x
    le = node_x[1] - node_x[0]
    n_el = node_x.shape[0] - 1
    x = jnp.clip(x, node_x[0], node_x[-1])
    e = jnp.clip(jnp.floor((x - node_x[0]) / le).astype(jnp.int32), 0, n_el - 1)
    xi = (x - node_x[e]) / le
    n1, n2, n3, n4 = shape_functions(xi, model.element_phi, le)
    s = model.shapes  # [m, n, 2]
    w1 = jnp.moveaxis(s[:, e, 0], 0, -1)
    t1 = jnp.moveaxis(s[:, e, 1], 0, -1)
    w2 = jnp.moveaxis(s[:, e + 1, 0], 0, -1)
    t2 = jnp.moveaxis(s[:, e + 1, 1], 0, -1)
    return (n1[..., None] * w1 + n2[..., None] * t1 + n3[..., None] * w2
            + n4[..., None] * t2)


def interpolate_nodal(model: ModalModel, nodal, x) -> jax.Array:
    """Rail nodal fields ``nodal`` [n_nodes, 2, k] (w-like, theta-like) at position ``x`` [m]
    (scalar) with the element's Timoshenko shape functions -> [k]; clamps to the rail ends.

    The interpolation of :func:`mode_shapes_at` on node-major data (each call gathers two
    contiguous rows). Pure ``jax.numpy``.
    """
    node_x = model.node_x
    le = node_x[1] - node_x[0]
    xc = jnp.clip(x, node_x[0], node_x[-1])
    e = jnp.clip(jnp.floor((xc - node_x[0]) / le).astype(jnp.int32), 0, node_x.shape[0] - 2)
    n1, n2, n3, n4 = shape_functions((xc - node_x[e]) / le, model.element_phi, le)
    a, b = nodal[e], nodal[e + 1]
    return n1 * a[0] + n2 * a[1] + n3 * b[0] + n4 * b[1]


def residual_table_is_periodic(model: ModalModel) -> jax.Array:
    """Whether the model's residual tables span one bay (a uniform track: read ``x mod L_S``)
    rather than the whole rail (supports that vary: read at the absolute ``x``). Told by the
    table's span, so it also works under ``jit`` (a traced bool)."""
    return model.residual_x[-1] - model.residual_x[0] < 1.5 * model.sleeper_spacing


def read_residual_table(model: ModalModel, table, x) -> jax.Array:
    """``table`` [n_res, ...] on the model's residual grid (``model.residual_x``) read at rail
    position ``x`` [m] (a scalar; any shape for a 1-D table), linear between the points:
    periodically across the bay for a uniform track, at the absolute position (clamped to the
    rail ends) otherwise. Returns [...]. Pure ``jax.numpy``."""
    grid = model.residual_x
    s = jnp.where(residual_table_is_periodic(model), jnp.mod(x, model.sleeper_spacing),
                  x - grid[0])
    u = s / (grid[1] - grid[0])
    k = jnp.clip(jnp.floor(u).astype(jnp.int32), 0, grid.shape[0] - 2)
    w = jnp.clip(u - k, 0.0, 1.0)
    return (1 - w) * table[k] + w * table[k + 1]


def residual_compliance_at(model: ModalModel, x) -> jax.Array:
    """Static compliance [m/N] of the truncated modes at (x, x).

    A table across one bay (uniform track) is read periodically, ``x mod L_S``; a table along
    the whole rail (supports that vary) is read at the absolute position ``x`` (clamped to
    the rail ends): :func:`residual_table_is_periodic`.
    ``x`` [m] any shape; returns float [...]. Pure ``jax.numpy``.
    """
    x = jnp.asarray(x, dtype=jnp.result_type(x, float))  # float32 stays float32
    return read_residual_table(model, model.residual, x)


def modal_receptance(model: ModalModel, freqs, x: float = 0.0) -> np.ndarray:
    """Point receptance [m/N] at ``x`` [m] from the modal model, complex [n_f] (freqs in Hz).

    Includes the static residual of the truncated modes.
    """
    return (modal_sum(model, freqs, float(x), float(x))
            + float(residual_compliance_at(model, float(x))))


def modal_sum(model: ModalModel, freqs, x_force: float, x_response: float) -> np.ndarray:
    """The kept modes' receptance [m/N] from a force at ``x_force`` [m] to the displacement
    at ``x_response`` [m], complex [n_f] (freqs [Hz]); without the truncated modes' static
    part (the caller adds it)."""
    f = _check_freqs(freqs)
    s = 2j * np.pi * f[:, None]
    a = np.asarray(model.weights) * np.asarray(mode_shapes_at(model, x_force)) * np.asarray(
        mode_shapes_at(model, x_response))
    lam = np.asarray(model.poles)
    # pairs: (w/2) [a/(s - lam) + conj(a)/(s - conj(lam))]; real poles: a/(s - lam), w = 1
    pair = np.asarray(model.weights) > 1.5
    h = np.where(pair, 0.5 * (a / (s - lam) + np.conj(a) / (s - np.conj(lam))), a / (s - lam))
    return h.sum(axis=1)


def _mirror_bases(fe: FEModel, n_bays: int) -> list[scipy.sparse.csc_matrix]:
    """Orthonormal bases of the symmetric and antisymmetric DOF subspaces about x = 0.

    The clamped track is mirror symmetric about the middle sleeper when ``n_bays`` is even:
    w(x) -> w(-x), theta(x) -> -theta(-x). Symmetric and antisymmetric modes then decouple
    (also through the damping), which halves the eigenproblems (4-8x faster). For odd
    ``n_bays`` the identity basis is returned.
    """
    n_dof = fe.stiffness.shape[0]
    if n_bays % 2:
        return [scipy.sparse.identity(n_dof, format="csc")]
    n_nodes = fe.node_x.size
    node = np.arange(1, n_nodes - 1)
    rail_p = np.stack([2 * (n_nodes - 1 - node) - 2, 2 * (n_nodes - 1 - node) - 1], 1).ravel()
    rail_s = np.tile([1.0, -1.0], node.size)
    j = np.arange(1, n_bays)
    perm = np.concatenate([rail_p, fe.n_rail_dof + (n_bays - j) - 1])
    sign = np.concatenate([rail_s, np.ones(j.size)])
    bases = []
    for parity in (1.0, -1.0):
        rows, cols, vals = [], [], []
        col = 0
        for i in range(n_dof):
            q = perm[i]
            if q > i:
                rows += [i, q]
                vals += [1 / np.sqrt(2), parity * sign[i] / np.sqrt(2)]
                cols += [col, col]
                col += 1
            elif q == i and sign[i] == parity:
                rows.append(i)
                vals.append(1.0)
                cols.append(col)
                col += 1
        bases.append(scipy.sparse.csc_matrix((vals, (rows, cols)), shape=(n_dof, col)))
    return bases


def _point_compliance_banded(fe: FEModel, x: np.ndarray) -> np.ndarray:
    """Static point compliance K^-1(x, x) [m/N] at many rail positions ``x`` [n_x].

    Only the 4 x 4 blocks of K^-1 over each element's DOFs are needed. K is banded after a
    reverse Cuthill-McKee ordering (bandwidth p ~ 7), and the entries of K^-1 inside that
    band follow from the banded Cholesky factor by the Takahashi recurrence (Takahashi,
    Fagan & Chin 1973), O(n p^2): far cheaper than thousands of solves.
    """
    k = scipy.sparse.csr_matrix(fe.stiffness)
    n = k.shape[0]
    perm = scipy.sparse.csgraph.reverse_cuthill_mckee(k, symmetric_mode=True)
    pos = np.empty(n, dtype=int)
    pos[perm] = np.arange(n)
    kp = scipy.sparse.triu(k[perm][:, perm]).tocoo()
    p = int(np.max(kp.col - kp.row))
    ab = np.zeros((p + 1, n))
    ab[p + kp.row - kp.col, kp.col] = kp.data
    u = scipy.linalg.cholesky_banded(ab, check_finite=False)  # K = U^T U, U upper banded
    d = u[p] ** 2  # K = L D L^T with L = U^T diag(U)^-1 unit lower
    lower = np.zeros((n + p, p))  # lower[i, r] = L[i + 1 + r, i]
    for r in range(p):
        lower[: n - r - 1, r] = u[p - 1 - r, r + 1:] / u[p, : n - r - 1]
    z = np.zeros((n + p, p + 1))  # z[i, r] = Z[i, i + r] (Z = K^-1, zero beyond the end)
    for i in range(n - 1, -1, -1):
        li = lower[i]  # L[i+1 .. i+p, i]
        # Z[i+1+a, i+1+b] for a, b < p from the band of later rows
        a = np.arange(p)
        lo, hi = np.minimum.outer(a, a), np.maximum.outer(a, a)
        blk = z[i + 1 + lo, hi - lo]
        zi = -blk @ li  # Z[i, i+1+b]
        z[i, 1:] = zi
        z[i, 0] = 1.0 / d[i] - li @ zi
    # element DOFs and shape functions of every position (as _load_vector)
    n_el = fe.node_x.size - 1
    e = np.clip(np.floor((x - fe.node_x[0]) / fe.element_length).astype(int), 0, n_el - 1)
    xi = (x - fe.node_x[e]) / fe.element_length
    nf = np.stack(shape_functions(xi, fe.phi, fe.element_length), axis=1)  # [n_x, 4]
    g = np.stack([2 * e, 2 * e + 1, 2 * e + 2, 2 * e + 3], axis=1) - 2
    ok = (g >= 0) & (g < fe.n_rail_dof)
    nf = np.where(ok, nf, 0.0)
    pg = pos[np.where(ok, g, 0)]  # permuted positions [n_x, 4]
    first_free = pg[np.arange(g.shape[0]), np.argmax(ok, axis=1)]
    pg = np.where(ok, pg, first_free[:, None])  # clamped DOFs (nf = 0) point at a free one
    pa, pb = pg[:, :, None], pg[:, None, :]
    zab = z[np.minimum(pa, pb), np.abs(pa - pb)]  # [n_x, 4, 4]; |pa - pb| <= p (one element)
    return np.einsum("ja,jab,jb->j", nf, zab, nf)


def _modal_arrays(track: Track, max_frequency: float, n_residual: int) -> dict[str, np.ndarray]:
    fe = assemble(track)
    w_max = 2 * np.pi * max_frequency
    nb = int(track.n_bays)
    # the mirror split needs supports symmetric about x = 0 (always so for a uniform track;
    # a uniform track with odd n_bays gets the identity basis, as it always has)
    symmetric = is_uniform(track) or is_mirror_symmetric(track)
    parts = []
    # supports that vary: the full problem (the identity basis). Every mode by divide and
    # conquer, then the kept ones: 2.5x faster here than the kept modes alone by MRRR
    # (LAPACK's eigh(subset_by_value) after a Cholesky reduction; benchmarks/README.md)
    identity = [scipy.sparse.identity(fe.stiffness.shape[0], format="csc")]
    for basis in _mirror_bases(fe, nb) if symmetric else identity:
        k = (basis.T @ fe.stiffness @ basis).toarray()
        m = (basis.T @ fe.mass @ basis).toarray()
        w2, vec = scipy.linalg.eigh(k, m, driver="gvd", check_finite=False)
        keep = w2 <= w_max**2
        vec = basis @ vec[:, keep]
        c_modal = vec.T @ (fe.damping @ vec)
        lam, wts, a = complex_modes(w2[keep], c_modal)
        parts.append((lam, wts, real_times_complex(vec, a)))
    poles = np.concatenate([p[0] for p in parts])
    order = np.argsort(np.abs(poles))
    poles = poles[order]
    weights = np.concatenate([p[1] for p in parts])[order]
    u = np.concatenate([p[2] for p in parts], axis=1)[:, order]  # [n_dof, n_modes]
    n_nodes = fe.node_x.size
    shapes = np.zeros((poles.size, n_nodes, 2), dtype=complex)
    shapes[:, 1:-1, :] = u[: fe.n_rail_dof].T.reshape(poles.size, n_nodes - 2, 2)
    sleeper_shapes = u[fe.n_rail_dof:].T  # [n_modes, n_sleepers]

    # static correction of the truncated modes: across the central bay (uniform track,
    # periodic), else along the whole rail in absolute coordinates
    ls = float(track.sleeper_spacing)
    if is_uniform(track):
        res_x = np.linspace(0.0, ls, n_residual)
    else:
        res_x = np.linspace(fe.node_x[0], fe.node_x[-1], (n_residual - 1) * nb + 1)
    b = _load_vector(fe, res_x)
    if res_x.size == n_residual:
        full = np.einsum("ij,ij->j", b.toarray(),
                         scipy.sparse.linalg.splu(fe.stiffness).solve(b.toarray()))
    else:  # thousands of positions along the rail: the band of K^-1, not thousands of solves
        full = _point_compliance_banded(fe, res_x)
    phi = (b.T @ u)  # [n_res, n_modes]: the same Timoshenko interpolation as mode_shapes_at
    kept = np.real(phi**2 @ (weights / -poles))
    residual = full - kept
    return {"poles": poles, "weights": weights, "node_x": fe.node_x, "shapes": shapes,
            "residual_x": res_x, "residual": residual, "sleeper_spacing": np.array(ls),
            "element_phi": np.array(fe.phi), "sleeper_shapes": sleeper_shapes}


def modal_model(track: Track, max_frequency: float = 20e3, cache_dir=None,
                n_residual: int = 33, use_cache: bool = True) -> ModalModel:
    """Complex-mode model of the track with a static correction (cached on disk).

    Method: undamped real modes of (K, M) below ``max_frequency`` (``scipy.linalg.eigh``),
    the non-proportional pad/ballast damping projected onto them, complex modes of the reduced
    2n x 2n state-space system (:func:`wfjax.model.modal.complex_modes`), mode shapes mapped back
    to the rail nodes, and the static compliance of the truncated modes tabulated across one
    bay (``n_residual`` points). Speed independent; cached with :mod:`wfjax._cache` keyed by
    every track parameter, ``max_frequency``, ``n_residual`` and the wfjax version.

    Supports that vary from sleeper to sleeper (:mod:`wfjax.model.supports`): the cache key holds
    the per-sleeper arrays; the symmetric/antisymmetric split is used only when the supports
    are mirror symmetric about ``x = 0``, else the full eigenproblem is solved; the residual
    is tabulated along the whole rail (``n_residual - 1`` intervals per bay) and read at
    absolute positions (:func:`residual_compliance_at`).

    Args:
        track: track parameters (concrete numbers).
        max_frequency: highest undamped natural frequency kept [Hz] (> 0).
        cache_dir: cache directory (default ``$WFJAX_CACHE_DIR`` or ``~/.cache/wfjax``).
        n_residual: points of the residual table across the bay (>= 2).
        use_cache: ``False`` always rebuilds and does not touch the disk.

    Returns:
        :class:`ModalModel` with jax arrays.
    """
    max_frequency = _check_positive_scalar("max_frequency", max_frequency, "Hz")
    if not isinstance(n_residual, (int, np.integer)) or n_residual < 2:
        raise ValueError(f"n_residual must be an integer >= 2, got {n_residual!r}")
    p = _track_numbers(track)

    def build():
        return _modal_arrays(track, max_frequency, int(n_residual))

    if use_cache:
        key = {**p, "n_bays": int(track.n_bays), "elements_per_bay": int(track.elements_per_bay),
               "max_frequency": max_frequency, "n_residual": int(n_residual), "scheme": 2}
        if not is_uniform(track):
            key["supports"] = "per-sleeper arrays; residual along the rail"
        arrays = _cache.load_or_build("track-modal", key, build, cache_dir)
    else:
        arrays = build()
    return ModalModel(
        to_device(arrays["poles"]), to_device(arrays["weights"]),
        to_device(arrays["node_x"]), to_device(arrays["shapes"]),
        to_device(arrays["residual_x"]), to_device(arrays["residual"]),
        float(arrays["sleeper_spacing"]), float(arrays["element_phi"]),
        to_device(arrays["sleeper_shapes"]))


# --------------------------------------------------------------------------------------------
# moving Green's functions
# --------------------------------------------------------------------------------------------
class MovingGreens(NamedTuple):
    """Moving Green's functions of the rail (Eq. 5).

    Fields:
        t: float [n_t] times t_n = n dt [s] (t_0 = 0).
        x0: float [n_x0] excitation positions [m] (0 = above the middle sleeper).
        g: float [n_x0, n_t] rail displacement at x0 + v t_n per unit impulse at x0 at t = 0
            [m/(N s)] (the dynamic part: the kept modes).
        residual: float [n_x0] static compliance [m/N] of the truncated modes at x0: the
            complete response to a force history is
            xi_R(t) = int_0^t F(tau) g^{v tau}(t - tau) dtau + residual(x(t)) F(t).
        speed: v [m/s].
    """

    t: np.ndarray
    x0: np.ndarray
    g: np.ndarray
    residual: np.ndarray
    speed: float


def default_duration(track: Track) -> float:
    """Default truncation length of the moving Green's functions [s].

    0.1 s. The response decays to about 1 % of its peak within 20-40 ms; what is left is a
    lightly damped ringing of the rail (see the benchmark README) that stays at 0.1-1 % of
    the peak. Comparing 70 and 140 bays shows that this tail is not a reflection from the
    clamped ends (the difference is < 0.5 % of the peak over 0.1 s). The time loop itself
    uses the modal states (no truncation); this length only matters for tabulated g.
    """
    return 0.1


def _check_x0(track: Track, x0) -> np.ndarray:
    ls = float(track.sleeper_spacing)
    if x0 is None:
        return np.linspace(0.0, ls, 27)
    x0 = np.atleast_1d(np.asarray(x0, dtype=float))
    half = (int(track.n_bays) // 2 - 1) * ls
    if x0.ndim != 1 or not np.all(np.isfinite(x0)) or np.any(np.abs(x0) > half):
        raise ValueError(f"x0 must be finite positions within [-{half:g}, {half:g}] m, "
                         f"got {x0!r}")
    return x0


def _time_grid(duration, dt) -> np.ndarray:
    duration = _check_positive_scalar("duration", duration, "s")
    dt = _check_positive_scalar("dt", dt, "s")
    if dt > duration:
        raise ValueError(f"dt must be <= duration ({duration:g} s), got {dt!r} s")
    return np.arange(int(round(duration / dt)) + 1) * dt


@jax.jit
def _modal_greens(model: ModalModel, x0, t, speed):
    """g [n_x0, n_t]; time in chunks of 1024 samples to bound memory (n_t x n_modes)."""
    chunk = 1024
    n_t = t.shape[0]
    n_c = -(-n_t // chunk)
    tc = jnp.pad(t, (0, n_c * chunk - n_t), mode="edge").reshape(n_c, chunk)

    def one(x):
        phi0 = model.weights * mode_shapes_at(model, x)  # [m]

        def part(tt):
            phit = mode_shapes_at(model, x + speed * tt)  # [chunk, m]
            return jnp.real(jnp.sum(phi0 * phit * jnp.exp(model.poles[None, :] * tt[:, None]),
                                    axis=-1))

        return jax.lax.map(part, tc).reshape(-1)[:n_t]

    return jax.lax.map(one, x0)


def moving_greens(track: Track, speed: float, x0=None, duration: float | None = None,
                  dt: float = 2.5e-5, model: ModalModel | None = None,
                  max_frequency: float = 20e3, cache_dir=None) -> MovingGreens:
    """Moving Green's functions g(x0, t) from the complex-mode model (Eq. 5).

    g(x0, t_n) = Re sum_r w_r phi_r(x0 + v t_n) phi_r(x0) exp(lambda_r t_n), the rail
    displacement at the point moving with the wheel due to a unit impulse at x0 at t = 0.
    The modes above ``max_frequency`` enter as the static term ``residual`` (see
    :class:`MovingGreens`).

    Args:
        track: track parameters.
        speed: train speed v [m/s] (> 0).
        x0: [n_x0] excitation positions [m]; default 27 points across the central bay
            [0, L_S] (2.5 cm apart).
        duration: truncation length [s] (default :func:`default_duration`, 0.1 s).
        dt: sampling time step [s] (default 25 us, the simulation's largest step).
        model: a precomputed :func:`modal_model` (default: built / loaded from the cache).
        max_frequency, cache_dir: passed to :func:`modal_model`.

    Returns:
        :class:`MovingGreens` (numpy arrays).
    """
    speed = _check_positive_scalar("speed", speed, "m/s")
    x0 = _check_x0(track, x0)
    t = _time_grid(default_duration(track) if duration is None else duration, dt)
    if np.max(x0) + speed * t[-1] > float(track.n_bays // 2 - 1) * float(track.sleeper_spacing):
        raise ValueError(f"speed * duration = {speed * t[-1]:.2f} m runs off the "
                         f"{track.n_bays}-bay track; shorten duration or add bays")
    if model is None:
        model = modal_model(track, max_frequency, cache_dir)
    g = np.asarray(_modal_greens(model, jnp.asarray(x0), jnp.asarray(t), speed))
    res = np.asarray(residual_compliance_at(model, jnp.asarray(x0)))
    return MovingGreens(t, x0, g, res, speed)


def moving_greens_newmark(track: Track, speed: float, x0, duration: float, dt: float = 2.5e-5,
                          substeps: int = 10) -> MovingGreens:
    """Moving Green's functions by direct time integration of the full FE model (reference).

    Newmark average-acceleration (trapezoidal) integration of M q'' + C q' + K q = 0 from
    q(0) = 0, q'(0) = M^-1 N(x0) (the unit impulse at x0), with step dt / substeps, observed
    at x0 + v t_n through the element shape functions. Independent of the modal route (no
    eigenvectors, no truncation). Its period error is (omega h)^2 / 12.

    Args: as :func:`moving_greens`; ``substeps`` (>= 1) integration steps per output step.

    Returns:
        :class:`MovingGreens` with ``residual`` zero (all modes are in ``g``).
    """
    speed = _check_positive_scalar("speed", speed, "m/s")
    x0 = _check_x0(track, x0)
    t = _time_grid(duration, dt)
    if not isinstance(substeps, (int, np.integer)) or substeps < 1:
        raise ValueError(f"substeps must be an integer >= 1, got {substeps!r}")
    fe = assemble(track)
    k, m, c = fe.stiffness, fe.mass, fe.damping
    h = dt / substeps
    lu = scipy.sparse.linalg.splu((k + (2 / h) * c + (4 / h**2) * m).tocsc())
    lu_m = scipy.sparse.linalg.splu(m.tocsc())
    g = np.zeros((x0.size, t.size))
    for i, xi in enumerate(x0):
        obs = _load_vector(fe, xi + speed * t)  # [n_dof, n_t]
        q = np.zeros(k.shape[0])
        v = lu_m.solve(_load_vector(fe, xi).toarray()[:, 0])
        a = lu_m.solve(-(c @ v))
        hist = np.zeros((t.size, q.size))
        for n in range(1, t.size):
            for _ in range(substeps):
                rhs = m @ ((4 / h**2) * q + (4 / h) * v + a) + c @ ((2 / h) * q + v)
                q_new = lu.solve(rhs)
                v_new = (2 / h) * (q_new - q) - v
                a = (4 / h**2) * (q_new - q) - (4 / h) * v - a
                q, v = q_new, v_new
            hist[n] = q
        g[i] = np.asarray(obs.multiply(hist.T).sum(axis=0)).ravel()
    return MovingGreens(t, x0, g, np.zeros(x0.size), speed)

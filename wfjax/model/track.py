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
* :func:`wfjax.model.greens.moving_greens` -- moving Green's functions g(x0, t) (Eq. 5) from
  the modal model, with a direct time integration of the full FE model as its check.
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
from .._parallel import dense_threads
from .._xla import to_device
from ..params import Track
from . import ends as ends_mod
from .beam import element_interior_compliance, fraction_in_element, shape_functions, track_numbers
from .fe import FEModel, assemble, element_dofs, load_vector
from .modal import complex_modes, discrete_step_coefficients, real_times_complex
from .periodic import periodic_receptance
from .sleepers import is_mirror_symmetric, is_uniform

__all__ = [
    "ModalModel",
    "receptance",
    "periodic_receptance",
    "static_deflection",
    "modal_model",
    "mode_shapes_at",
    "interpolate_nodal",
    "residual_compliance_at",
    "modal_receptance",
    "modal_sum",
    "discrete_step_coefficients",
]


def _check_freqs(freqs) -> np.ndarray:
    f = np.asarray(freqs, dtype=float)
    if f.ndim > 1 or f.size == 0 or not np.all(np.isfinite(f)) or np.any(f < 0):
        raise ValueError(f"freqs must be a non-empty 1-D array of finite frequencies >= 0 Hz, "
                         f"got {freqs!r}")
    return np.atleast_1d(f)


def check_positive_scalar(name: str, value, unit: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a number > 0 {unit}, got {value!r}") from exc
    if not math.isfinite(v) or v <= 0:
        raise ValueError(f"{name} must be finite and > 0 {unit}, got {value!r} "
                         f"(allowed range: (0, inf) {unit})")
    return v


def receptance(track: Track, freqs, x: float = 0.0, x_response=None) -> np.ndarray:
    """Rail receptance [m/N] by a direct sparse frequency-domain solve of the FE model (the
    finite track with clamped ends; :func:`periodic_receptance` for the infinite track).

    Args:
        track: the track parameters.
        freqs: [n_f] frequencies [Hz] (>= 0).
        x: excitation position [m] (0 = above the middle sleeper, L_S/2 = midspan).
        x_response: response position(s) [m], scalar or [n_r]; default ``x`` (point receptance).

    Returns:
        complex [n_f] (scalar ``x_response``) or [n_f, n_r]: displacement at ``x_response``
        per unit harmonic force at ``x`` (convention exp(i omega t)). A point receptance
        includes the load's deflection inside its element that the shape functions miss
        (:func:`wfjax.model.fe.element_interior_compliance`, static).
    """
    f = _check_freqs(freqs)
    fe = assemble(track)
    scalar = x_response is None or np.ndim(x_response) == 0
    xr = x if x_response is None else x_response
    b = load_vector(fe, x).toarray()[:, 0]
    nr = load_vector(fe, xr)  # [n_dof, n_r]
    out = np.empty((f.size, nr.shape[1]), dtype=complex)
    k, m, c = fe.stiffness, fe.mass, fe.damping
    for i, fi in enumerate(f):
        w = 2 * np.pi * fi
        d = (k - w**2 * m + 1j * w * c).tocsc()
        u = scipy.sparse.linalg.spsolve(d, b.astype(complex))
        out[i] = nr.T @ u
    if x_response is None:  # a point receptance: the load's own in-element deflection
        out += element_interior_compliance(track, element_fraction(fe, np.array([x])))
    return out[:, 0] if scalar else out


def element_fraction(fe: FEModel, x) -> np.ndarray:
    """Position of rail coordinates ``x`` [m] within their elements, in [0, 1) (0 on nodes)."""
    return fraction_in_element(np.asarray(x, dtype=float) - fe.node_x[0], fe.element_length)


def static_deflection(track: Track, force: float = 118e3, x: float = 0.0) -> float:
    """Static rail deflection [m] at ``x`` [m] under a point force ``force`` [N] at ``x``."""
    force = check_positive_scalar("force", force, "N")
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
    (also through the damping), which halves the eigenproblems (4-8x faster). End networks
    mirror into each other (the left one is the right's image). For odd ``n_bays`` the
    identity basis is returned.
    """
    n_dof = fe.stiffness.shape[0]
    if n_bays % 2:
        return [scipy.sparse.identity(n_dof, format="csc")]
    perm, sign = np.arange(n_dof), np.ones(n_dof)
    nodes = fe.node_x.size
    mirrored = fe.rail_dofs.reshape(nodes, 2)[::-1].ravel()  # node j's partner: N - j
    free = fe.rail_dofs >= 0
    perm[fe.rail_dofs[free]] = mirrored[free]
    sign[fe.rail_dofs[free]] = np.tile([1.0, -1.0], nodes)[free]
    sleepers = fe.n_rail_dof + np.arange(n_bays - 1)
    perm[sleepers] = sleepers[::-1]
    first_aux = sleepers[-1] + 5  # end networks: the end nodes' 4 DOFs, then left, right
    n_aux = (n_dof - first_aux) // 2  # left aux i <-> right aux i
    if n_aux > 0:
        aux = first_aux + np.arange(n_aux)
        perm[aux], perm[aux + n_aux] = aux + n_aux, aux
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
    # element DOFs and shape functions of every position (as load_vector)
    n_el = fe.node_x.size - 1
    e = np.clip(np.floor((x - fe.node_x[0]) / fe.element_length).astype(int), 0, n_el - 1)
    xi = (x - fe.node_x[e]) / fe.element_length
    nf = np.stack(shape_functions(xi, fe.phi, fe.element_length), axis=1)  # [n_x, 4]
    g = element_dofs(fe, e)  # [n_x, 4]
    ok = g >= 0
    nf = np.where(ok, nf, 0.0)
    pg = pos[np.where(ok, g, 0)]  # permuted positions [n_x, 4]
    first_free = pg[np.arange(g.shape[0]), np.argmax(ok, axis=1)]
    pg = np.where(ok, pg, first_free[:, None])  # clamped DOFs (nf = 0) point at a free one
    pa, pb = pg[:, :, None], pg[:, None, :]
    zab = z[np.minimum(pa, pb), np.abs(pa - pb)]  # [n_x, 4, 4]; |pa - pb| <= p (one element)
    return np.einsum("ja,jab,jb->j", nf, zab, nf)


def _damper_augmentation(vec: np.ndarray, w2: np.ndarray, keep: np.ndarray,
                         dampers: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pseudo-modes that carry the truncated modes' quasi-static response to the
    sleepers' damper forces (modal truncation augmentation): ``(vectors [n, r], their
    squared frequencies [r] [rad^2/s^2])``.

    ``vec`` [n, n] and ``w2`` [n]: every mass-normalised real mode of (K, M); ``keep`` [n]:
    the kept ones; ``dampers`` [n, k]: the damping matrix's columns of the DOFs the pads and
    ballast act on. A damper force f excites a truncated mode t by phi_t^T f / w_t^2 below its
    resonance, and the static correction of the contact point alone leaves out that the
    pads feel it (their damping couples the kept and the truncated modes). The range of
    Phi_t W_t^-1 Phi_t^T C (r <= k vectors, M-orthonormal, M-orthogonal to the kept modes),
    diagonalised on K, joins the kept modes: the transfer receptance of the rail's shear
    comes within 0.04 % of a direct solve at 15 kHz instead of 3.1 % (docs/convergence.md).
    """
    vt, w2t = vec[:, ~keep], w2[~keep]
    if not vt.shape[1]:
        return vt, w2t
    u, s, _ = np.linalg.svd((vt.T @ dampers) / w2t[:, None], full_matrices=False)
    ur = u[:, : int(np.sum(s > 1e-8 * s[0]))]
    w2p, y = np.linalg.eigh(ur.T @ (w2t[:, None] * ur))
    return vt @ (ur @ y), w2p


def _modal_arrays(track: Track, max_frequency: float, n_residual: int) -> dict[str, np.ndarray]:
    fe = assemble(track)
    # the DOFs the sleepers' dampers act on: the sleepers and the rail's nodes on them
    dampers = fe.damping[:, np.unique(fe.damping[fe.n_rail_dof:].nonzero()[1])]
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
        with dense_threads(k.shape[0]):
            w2, vec = scipy.linalg.eigh(k, m, driver="gvd", check_finite=False)
            keep = w2 <= w_max**2
            extra, w2_extra = _damper_augmentation(vec, w2, keep,
                                                   (basis.T @ dampers).toarray())
            vec = basis @ np.concatenate([vec[:, keep], extra], axis=1)
            c_modal = vec.T @ (fe.damping @ vec)
            lam, wts, a = complex_modes(np.concatenate([w2[keep], w2_extra]), c_modal)
            parts.append((lam, wts, real_times_complex(vec, a)))
    poles = np.concatenate([p[0] for p in parts])
    order = np.argsort(np.abs(poles))
    poles = poles[order]
    weights = np.concatenate([p[1] for p in parts])[order]
    u = np.concatenate([p[2] for p in parts], axis=1)[:, order]  # [n_dof, n_modes]
    free = fe.rail_dofs >= 0
    shapes = np.zeros((poles.size, fe.rail_dofs.size), dtype=complex)
    shapes[:, free] = u[fe.rail_dofs[free]].T
    shapes = shapes.reshape(poles.size, fe.node_x.size, 2)
    sleeper_shapes = u[fe.n_rail_dof:fe.n_rail_dof + nb - 1].T  # [n_modes, n_sleepers]

    # static correction of the truncated modes: across the central bay (uniform track,
    # periodic), else along the whole rail in absolute coordinates
    ls = float(track.sleeper_spacing)
    if is_uniform(track):
        res_x = np.linspace(0.0, ls, n_residual)
    else:
        res_x = np.linspace(fe.node_x[0], fe.node_x[-1], (n_residual - 1) * nb + 1)
    b = load_vector(fe, res_x)
    if res_x.size == n_residual:
        full = np.einsum("ij,ij->j", b.toarray(),
                         scipy.sparse.linalg.splu(fe.stiffness).solve(b.toarray()))
    else:  # thousands of positions along the rail: the band of K^-1, not thousands of solves
        full = _point_compliance_banded(fe, res_x)
    phi = (b.T @ u)  # [n_res, n_modes]: the same Timoshenko interpolation as mode_shapes_at
    kept = np.real(phi**2 @ (weights / -poles))
    residual = full - kept + element_interior_compliance(track, element_fraction(fe, res_x))
    return {"poles": poles, "weights": weights, "node_x": fe.node_x, "shapes": shapes,
            "residual_x": res_x, "residual": residual, "sleeper_spacing": np.array(ls),
            "element_phi": np.array(fe.phi), "sleeper_shapes": sleeper_shapes}


RESIDUAL_POINTS_PER_ELEMENT = 8  # intervals of the residual table per rail element


def modal_model(track: Track, max_frequency: float = 20e3, cache_dir=None,
                n_residual: int | None = None, use_cache: bool = True) -> ModalModel:
    """Complex-mode model of the track with a static correction (cached on disk).

    Method: undamped real modes of (K, M) below ``max_frequency`` (``scipy.linalg.eigh``),
    joined by the pseudo-modes of the truncated modes' quasi-static response to the pads' and
    ballast's damper forces (:func:`_damper_augmentation`: their damping couples the kept and
    the truncated modes; one per damper, 46 on the default track), the non-proportional
    pad/ballast damping projected onto them, complex modes of the reduced
    2n x 2n state-space system (:func:`wfjax.model.modal.complex_modes`), mode shapes mapped back
    to the rail nodes, and the static compliance of the truncated modes tabulated across one
    bay (``n_residual`` points), plus the part of a point load's static deflection inside an
    element that the shape functions miss (:func:`wfjax.model.fe.element_interior_compliance`:
    without it the contact point is too stiff between the nodes, and the impact force
    converged only to first order in the mesh). Speed independent; cached with
    :mod:`wfjax._cache` keyed by every track parameter, ``max_frequency``, ``n_residual`` and
    the wfjax version.

    Supports that vary from sleeper to sleeper (:mod:`wfjax.model.supports`): the cache key holds
    the per-sleeper arrays; the symmetric/antisymmetric split is used only when the supports
    are mirror symmetric about ``x = 0``, else the full eigenproblem is solved; the residual
    is tabulated along the whole rail (``n_residual - 1`` intervals per bay) and read at
    absolute positions (:func:`residual_compliance_at`).

    Args:
        track: track parameters (concrete numbers).
        max_frequency: highest undamped natural frequency kept [Hz] (> 0).
        cache_dir: cache directory (default ``$WFJAX_CACHE_DIR`` or ``~/.cache/wfjax``).
        n_residual: points of the residual table across the bay (>= 2); default
            ``8 elements_per_bay + 1`` (65 for 8 elements), so that every FE node is a table
            point: the residual varies within an element and has kinks at the nodes (33
            points, the default before, were off by up to 70 % of the residual at 26
            elements per bay between misaligned points; docs/convergence.md).
        use_cache: ``False`` always rebuilds and does not touch the disk.

    Returns:
        :class:`ModalModel` with jax arrays.
    """
    max_frequency = check_positive_scalar("max_frequency", max_frequency, "Hz")
    track = ends_mod.resolved(track)
    if n_residual is None:
        n_residual = RESIDUAL_POINTS_PER_ELEMENT * int(track.elements_per_bay) + 1
    if not isinstance(n_residual, (int, np.integer)) or n_residual < 2:
        raise ValueError(f"n_residual must be an integer >= 2, got {n_residual!r}")
    p = track_numbers(track)

    def build():
        return _modal_arrays(track, max_frequency, int(n_residual))

    if use_cache:
        key = {**p, "n_bays": int(track.n_bays), "elements_per_bay": int(track.elements_per_bay),
               "absorbing_sleepers": int(track.absorbing_sleepers),
               "max_frequency": max_frequency, "n_residual": int(n_residual), "scheme": 5}
        if track.ends == "network":
            key["end_network"] = (ends_mod.stored()["fit"] if ends_mod.is_stored(track)
                                  else ends_mod.FIT_KEY)
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



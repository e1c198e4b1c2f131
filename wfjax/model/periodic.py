"""Receptances of the infinite periodic track: the FE rail on identical discrete supports,
without ends (wave finite elements).

A finite clamped track cannot give the receptance at the pinned-pinned resonance: there
the rail's waves have nodes at the sleepers, the pads barely damp them, and the clamped
ends' standing waves shape the peak at any length (800 against 1000 bays: 10 % apart at
943 Hz; ``benchmarks/receptance_length.py``). The infinite track has no ends: at each
frequency its semi-infinite halves act on a finite section through exact boundary
stiffnesses, built from the decaying Floquet waves of one bay (Mead 1973; the wave finite
element method of Mace, Duhamel, Brennan & Hinke 2005):

1. one *cell* (a bay: the rail elements from a sleeper to the next, the sleeper's pad,
   mass and ballast at its left node) condensed at the frequency to its end nodes,
   D = [[D_LL, D_LR], [D_RL, D_RR]] (4 x 4 on w, theta of each end);
2. the Floquet waves u_{n+1} = lambda u_n: (D_RL + lambda (D_LL + D_RR) + lambda^2 D_LR)
   phi = 0, four multipliers in pairs lambda, 1 / lambda; with damping none lies on the unit
   circle, so two decay to the right (|lambda| < 1) and two to the left;
3. the right half's boundary stiffness K_R = D_LL + D_LR Phi Lambda Phi^-1 (the force at
   its first node that holds it at u_0, its waves decaying away), the left half's
   K_L = D_RR + D_RL Psi Lambda'^-1 Psi^-1; computed by cyclic reduction of the chain of
   cells (:func:`_semi_infinite`), which gives the same without the eigenvectors, which
   are ill-conditioned where two waves decay alike;
4. a section of a few cells, K_L and K_R at its ends, solved for the harmonic load.

The result is the infinite track's receptance to the FE discretisation, with no length to
converge. Scalar supports only (a periodic track); a hanging sleeper's ballast is left out
as in the finite model (:func:`wfjax.model.fe.assemble`).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg

from ..params import Track
from .beam import (
    element_interior_compliance,
    element_matrices,
    element_shapes,
    fraction_in_element,
    track_numbers,
)

__all__ = ["periodic_receptance", "floquet_multipliers"]


def _cell_matrices(p: dict, ne: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(K, M, C) of one cell [n, n], n = 2 (ne + 1) + 1: the rail dofs of nodes 0..ne, then
    the sleeper (pad from rail node 0, ballast to the ground); and the elements' shear
    parameter phi."""
    le = float(p["sleeper_spacing"]) / ne
    ke, me, phi = element_matrices(p["bending_stiffness"], p["shear_stiffness"], p["rail_mass"],
                                 p["rail_rotary_inertia"], le)
    n = 2 * (ne + 1) + 1
    k, m, c = np.zeros((n, n)), np.zeros((n, n)), np.zeros((n, n))
    for e in range(ne):
        s = slice(2 * e, 2 * e + 4)
        k[s, s] += ke
        m[s, s] += me
    bonded = float(p["ballast_gap"]) == 0  # a hanging sleeper: no linear ballast, as in fe
    kb, cb = (float(p["ballast_stiffness"]), float(p["ballast_damping"])) if bonded else (0, 0)
    kp, cp, sl = float(p["pad_stiffness"]), float(p["pad_damping"]), n - 1
    for mat, pad, ground in ((k, kp, kb), (c, cp, cb)):
        mat[0, 0] += pad
        mat[sl, sl] += pad + ground
        mat[0, sl] -= pad
        mat[sl, 0] -= pad
    m[sl, sl] += float(p["sleeper_mass"])
    return k, m, c, phi


def _condensed(cell: np.ndarray) -> np.ndarray:
    """The cell's dynamic stiffness [..., n, n] condensed to its end nodes' (w, theta):
    [..., 4, 4] (leading axes batched, e.g. frequencies)."""
    n = cell.shape[-1]
    b = np.array([0, 1, n - 3, n - 2])
    i = np.setdiff1d(np.arange(n), b)
    rows_b, rows_i = cell[..., b, :], cell[..., i, :]
    return rows_b[..., b] - rows_b[..., i] @ np.linalg.solve(rows_i[..., i], rows_i[..., b])


def _waves(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Floquet multipliers [4] and their node displacement vectors [2, 4] of condensed cell
    stiffness ``d`` [4, 4]: (D_RL + lambda (D_LL + D_RR) + lambda^2 D_LR) phi = 0."""
    dll, dlr, drl, drr = d[:2, :2], d[:2, 2:], d[2:, :2], d[2:, 2:]
    zero, eye = np.zeros((2, 2)), np.eye(2)
    a = np.block([[zero, eye], [-drl, -(dll + drr)]])
    b = np.block([[eye, zero], [zero, dlr]])
    lam, vec = scipy.linalg.eig(a, b)
    return lam, vec[:2]


REDUCTION_TOL = 1e-14  # cyclic reduction stops when the far coupling is this small
REDUCTION_STEPS = 64  # at most 2^64 cells folded: beyond that the waves do not decay


def _semi_infinite(boundary: np.ndarray, inward: np.ndarray, outward: np.ndarray,
                   diagonal: np.ndarray) -> np.ndarray:
    """Boundary stiffness [..., 2, 2] of a semi-infinite chain of identical cells by cyclic
    reduction (the decimation of Sancho, Lopez Sancho & Rubio 1985): every second node is
    condensed out, doubling the cells per step, until the coupling to the far node is
    negligible. ``boundary``: the boundary node's own block; ``outward`` / ``inward``: a
    node's coupling to its outer / inner neighbour; ``diagonal``: an inner node's block; each
    [..., 2, 2], leading axes batched (each chain keeps the step where it converged).

    Unlike the Floquet eigenvectors, it needs no wave to be told from another, so it stays
    exact where two multipliers come close (1.36 and 5.9 kHz on the default track, where
    the eigenvector form was 1.3 % and a factor 5 off a 400-bay track)."""
    b, a1, a_out, a_in = boundary, diagonal, outward, inward
    out = np.array(b, dtype=complex)
    done = np.zeros(b.shape[:-2], dtype=bool)
    for _ in range(REDUCTION_STEPS):
        x = np.linalg.inv(a1)
        xa_in, xa_out = x @ a_in, x @ a_out
        b = b - a_out @ xa_in
        a1 = a1 - a_in @ xa_out - a_out @ xa_in
        a_in, a_out = -a_in @ xa_in, -a_out @ xa_out
        now = ~done & (np.abs(a_out).max(axis=(-2, -1))
                       <= REDUCTION_TOL * np.abs(b).max(axis=(-2, -1)))
        out[now] = b[now]
        done |= now
        if done.all():
            return out
    raise ValueError("a Floquet wave neither decays nor grows: an undamped track has no "
                     "unique infinite-track receptance at this frequency")


def _right_stiffness(d: np.ndarray) -> np.ndarray:
    """K_R [..., 2, 2]: the right semi-infinite track's boundary stiffness (the force at its
    first node that holds it at u_0, its waves decaying away) from the condensed cell
    ``d`` [..., 4, 4]."""
    return _semi_infinite(d[..., :2, :2], d[..., 2:, :2], d[..., :2, 2:],
                          d[..., :2, :2] + d[..., 2:, 2:])


def _half_stiffnesses(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(K_L, K_R) [2, 2]: the left and right semi-infinite tracks' boundary stiffnesses."""
    k_l = _semi_infinite(d[2:, 2:], d[:2, 2:], d[2:, :2], d[:2, :2] + d[2:, 2:])
    return k_l, _right_stiffness(d)


def floquet_multipliers(track: Track, freqs) -> np.ndarray:
    """Floquet multipliers lambda [n_f, 4] of one bay (u_{n+1} = lambda u_n from sleeper to
    sleeper) at ``freqs`` [Hz], sorted by modulus: two decaying to the right (|lambda| < 1),
    their reciprocals to the left. -ln|lambda| is a wave's decay per bay [Np].

    With damping the decaying pair are the eigenvalues of the bay's transfer on the decaying
    waves, u_1 = -(D_RR + K_R)^-1 D_RL u_0 (K_R by cyclic reduction): the eigenproblem of
    :func:`_waves` is ill-conditioned where two waves decay alike (at 1361.5 Hz on the
    default track it gave 2e-5 and 0.93 against 0.070 and 0.93). Without damping, where
    waves travel undecayed and the reduction does not converge, :func:`_waves`."""
    p, ne = _numbers(track), int(track.elements_per_bay)
    k, m, c, _ = _cell_matrices(p, ne)
    out = []
    for f in np.atleast_1d(np.asarray(freqs, dtype=float)):
        w = 2 * math.pi * f
        d = _condensed(k - w**2 * m + 1j * w * c)
        try:
            right = np.linalg.eigvals(-np.linalg.solve(d[2:, 2:] + _right_stiffness(d),
                                                        d[2:, :2]))
            lam = np.concatenate([right, 1.0 / right])
        except ValueError:
            lam = _waves(d)[0]
        out.append(lam[np.argsort(np.abs(lam))])
    return np.array(out)


def _numbers(track: Track) -> dict:
    p = dict(track_numbers(track))
    for name, v in p.items():
        if np.ndim(v) > 0:
            if not np.all(np.asarray(v) == np.ravel(v)[0]):
                raise ValueError(f"track.{name} varies from sleeper to sleeper: the periodic "
                                 "receptance needs the same support at every sleeper")
            p[name] = float(np.ravel(v)[0])
    p.setdefault("ballast_gap", 0.0)  # track_numbers leaves out a gap that is 0 everywhere
    return p


def periodic_receptance(track: Track, freqs, x: float = 0.0, x_response=None) -> np.ndarray:
    """Rail receptance [m/N] of the infinite periodic track (no ends; module docstring).

    Args:
        track: the track (scalar supports, or per-sleeper arrays that are all the same; its
            ``n_bays`` is not used).
        freqs: [n_f] frequencies [Hz] (>= 0).
        x: excitation position [m] (0 = above a sleeper, L_S/2 = midspan).
        x_response: response position(s) [m], scalar or [n_r]; default ``x`` (point
            receptance).

    Returns:
        complex [n_f] (scalar ``x_response``) or [n_f, n_r], convention exp(i omega t), as
        :func:`wfjax.model.track.receptance`, with the load's in-element deflection in a
        point receptance.
    """
    p, ne = _numbers(track), int(track.elements_per_bay)
    ls, le = float(p["sleeper_spacing"]), float(p["sleeper_spacing"]) / ne
    f = np.atleast_1d(np.asarray(freqs, dtype=float))
    if not np.all(np.isfinite(f)) or np.any(f < 0):
        raise ValueError(f"freqs must be finite and >= 0 Hz, got {freqs!r}")
    xr = np.atleast_1d(np.asarray(x if x_response is None else x_response, dtype=float))
    if not (math.isfinite(float(x)) and np.all(np.isfinite(xr))):
        raise ValueError(f"x and x_response must be finite positions [m], got x={x!r}, "
                         f"x_response={x_response!r}")
    reach = max(abs(float(x)), float(np.max(np.abs(xr))))
    half = int(math.ceil(reach / ls)) + 1  # cells either side of the sleeper at x = 0
    x0 = -half * ls
    k, m, c, phi = _cell_matrices(p, ne)
    loads = _nodal_loads(np.concatenate([[float(x)], xr]) - x0, le, ne, 2 * half, phi)
    out = np.empty((f.size, xr.size), dtype=complex)
    for i, fi in enumerate(f):
        w = 2 * math.pi * fi
        cell = k - w**2 * m + 1j * w * c
        u = np.linalg.solve(_section(cell, 2 * half, *_half_stiffnesses(_condensed(cell))),
                            loads[:, 0].astype(complex))
        out[i] = loads[:, 1:].T @ u
    if x_response is None:
        out += element_interior_compliance(track, fraction_in_element([float(x) - x0], le))
    return out[:, 0] if x_response is None or np.ndim(x_response) == 0 else out


def _section(cell: np.ndarray, n_cells: int, k_l: np.ndarray, k_r: np.ndarray) -> np.ndarray:
    """Dynamic stiffness of ``n_cells`` cells in a row (rail dofs, then their sleepers) with
    the semi-infinite halves' ``k_l`` at the first node and ``k_r`` at the last."""
    nc = cell.shape[0]
    n_rail = nc - 1  # rail dofs per cell, both end nodes
    step = n_rail - 2
    rails = step * n_cells + 2
    d = np.zeros((rails + n_cells,) * 2, dtype=complex)
    for j in range(n_cells):
        idx = np.concatenate([np.arange(j * step, j * step + n_rail), [rails + j]])
        d[np.ix_(idx, idx)] += cell
    d[:2, :2] += k_l
    d[rails - 2:rails, rails - 2:rails] += k_r
    return d


def _nodal_loads(s: np.ndarray, le: float, ne: int, n_cells: int, phi: float) -> np.ndarray:
    """[n_dof, n_s] nodal loads of unit forces at section coordinates ``s`` [m] (0 at the
    first node) on a section of ``n_cells`` cells of ``ne`` elements (rail dofs, then the
    sleepers' rows, zero)."""
    n_el = ne * n_cells
    out = np.zeros((2 * (n_el + 1) + n_cells, s.size))
    e, shapes = element_shapes(s, le, n_el, phi)
    for col in range(s.size):
        out[2 * e[col]:2 * e[col] + 4, col] = shapes[:, col]
    return out

"""The track's finite-element matrices: Friedman & Kosmatka (1993) two-node Rayleigh-Timoshenko
rail elements, rail pads, half-sleeper masses and ballast assembled on the free DOFs (the model
is described in :mod:`wfjax.model.track`), and the static solve on them."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from ..params import Track
from . import ends as ends_mod
from .beam import element_matrices, element_shapes, track_numbers


# --------------------------------------------------------------------------------------------
# finite-element model
# --------------------------------------------------------------------------------------------
class FEModel(NamedTuple):
    """Assembled FE matrices of the track (scipy CSC, free DOFs only).

    DOF order: rail nodes 1 .. N-1 as (w, theta) pairs, then the interior sleepers; with end
    networks (``Track.ends``) then the end nodes 0 and N (w, theta each) and the two
    networks' internal DOFs (left, right; :mod:`wfjax.model.ends`). Clamped end nodes have
    no DOF: ``rail_dofs`` maps every node's (w, theta) to its row.
    """

    stiffness: scipy.sparse.csc_matrix  # [n_dof, n_dof] N/m
    mass: scipy.sparse.csc_matrix       # [n_dof, n_dof] kg
    damping: scipy.sparse.csc_matrix    # [n_dof, n_dof] N s/m
    node_x: np.ndarray                  # [N+1] rail node positions [m] (including the ends)
    element_length: float               # [m]
    phi: float                          # shear parameter 12 EI / (kGA Le^2)
    n_rail_dof: int                     # 2 (N - 1): the interior nodes' (the sleepers follow)
    rail_dofs: np.ndarray               # [2 (N + 1)] row of node j's w (2 j), theta (2 j + 1);
    # -1 for a clamped end's


def element_dofs(fe: FEModel, e) -> np.ndarray:
    """[..., 4] the rows of element ``e``'s (w1, theta1, w2, theta2) ([...] ints), -1 where
    the node is clamped."""
    e = np.asarray(e)
    return fe.rail_dofs[2 * e[..., None] + np.arange(4)]


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
    The ends are :func:`wfjax.model.ends.resolved`'s: networks on free end nodes, or clamped
    ends whose last ``track.absorbing_sleepers`` sleepers have their pad and ballast damping
    graded up (:func:`end_grading`), and the rail over the same zone ((n + 1) bays at each
    end) a mass-proportional damping (:func:`end_rail_damping`).
    """
    track = ends_mod.resolved(track)
    p = track_numbers(track)
    nb, ne = int(track.n_bays), int(track.elements_per_bay)
    n_el = nb * ne
    le = p["sleeper_spacing"] / ne
    ke, me, phi = element_matrices(p["bending_stiffness"], p["shear_stiffness"],
                                   p["rail_mass"], p["rail_rotary_inertia"], le)
    n_rail, n_sl = 2 * (n_el - 1), nb - 1
    n_ends = 4 + 2 * ends_mod.N_AUX if track.ends == "network" else 0
    rail_dofs = np.full(2 * (n_el + 1), -1)
    rail_dofs[2:-2] = np.arange(n_rail)
    if n_ends:  # the end nodes are free, their DOFs after the sleepers
        rail_dofs[:2], rail_dofs[-2:] = n_rail + n_sl + np.r_[0, 1], n_rail + n_sl + np.r_[2, 3]

    e = np.arange(n_el)
    gdof = rail_dofs[2 * e[:, None] + np.arange(4)]  # [n_el, 4]
    rows = np.repeat(gdof, 4, axis=1).ravel()
    cols = np.tile(gdof, (1, 4)).ravel()
    ok = (rows >= 0) & (cols >= 0)
    rows, cols, mv = rows[ok], cols[ok], np.tile(me.ravel(), n_el)[ok]
    n_abs = int(track.absorbing_sleepers)
    eta = (end_rail_damping((e + 0.5) * le, n_el * le, (n_abs + 1) * p["sleeper_spacing"])
           if n_abs else np.zeros(n_el))  # [n_el] 1/s
    entries = {"k": [(rows, cols, np.tile(ke.ravel(), n_el)[ok])], "m": [(rows, cols, mv)],
               "c": [(rows, cols, np.repeat(eta, 16)[ok] * mv)]}  # eta times the mass entries
    for name, triple in _support_entries(track, p, n_rail).items():
        entries[name].append(triple)
    if n_ends:
        for name, triple in _network_entries(track, n_rail + n_sl).items():
            entries[name].append(triple)
    k, m, c = (_sparse(entries[n], n_rail + n_sl + n_ends) for n in "kmc")
    node_x = (np.arange(n_el + 1) * le) - (nb // 2) * p["sleeper_spacing"]
    return FEModel(k, m, c, node_x, le, phi, n_rail, rail_dofs)


def _sparse(triples, n: int) -> scipy.sparse.csc_matrix:
    """[n, n] the sum of the (rows, cols, values) ``triples``."""
    rows, cols, values = (np.concatenate(part) for part in zip(*triples, strict=True))
    return scipy.sparse.coo_matrix((values, (rows, cols)), shape=(n, n)).tocsc()


def _support_entries(track: Track, p: dict, n_rail: int) -> dict:
    """{"k", "m", "c"}: (rows, cols, values) of the pads, sleepers and ballast: the rail's w
    DOF of node j ne (j = 1 .. n_bays - 1) and sleeper DOF ``n_rail`` + j - 1."""
    nb, ne = int(track.n_bays), int(track.elements_per_bay)
    j = np.arange(1, nb)
    rw, sl = 2 * (j * ne) - 2, n_rail + j - 1
    s_rows, s_cols = np.concatenate([rw, sl, rw, sl]), np.concatenate([rw, sl, sl, rw])
    ones = np.ones(nb - 1)
    kp, kb, cp, cb, msl = (p[n] * ones for n in ("pad_stiffness", "ballast_stiffness",
                                                  "pad_damping", "ballast_damping",
                                                  "sleeper_mass"))
    hanging = p.get("ballast_gap", 0.0) * ones > 0  # one-sided: the linear model is open there
    grading = end_grading(nb - 1, int(track.absorbing_sleepers))
    kb, cb = np.where(hanging, 0.0, kb), np.where(hanging, 0.0, cb * grading)
    cp = cp * grading
    return {"k": (s_rows, s_cols, np.concatenate([kp, kp + kb, -kp, -kp])),
            "m": (sl, sl, msl),
            "c": (s_rows, s_cols, np.concatenate([cp, cp + cb, -cp, -cp]))}


def _network_entries(track: Track, first: int) -> dict:
    """{"k", "m", "c"}: (rows, cols, values) of the two end networks on DOFs ``first`` +
    (left end node w, theta, right end node w, theta, left's N_AUX, right's N_AUX); the left
    network is the right's mirror image (theta -> -theta)."""
    n_aux = ends_mod.N_AUX
    mirror = np.diag(np.r_[1.0, -1.0, np.ones(n_aux)])
    left = first + np.r_[0, 1, 4 + np.arange(n_aux)]
    right = first + np.r_[2, 3, 4 + n_aux + np.arange(n_aux)]
    rows = np.concatenate([np.repeat(left, left.size), np.repeat(right, right.size)])
    cols = np.concatenate([np.tile(left, left.size), np.tile(right, right.size)])
    return {name: (rows, cols, np.concatenate([(mirror @ a @ mirror).ravel(), a.ravel()]))
            for name, a in zip("kcm", ends_mod.network(track), strict=True)}


def load_vector(fe: FEModel, x) -> scipy.sparse.csc_matrix:
    """[n_dof, n_x] sparse matrix whose columns are the nodal loads of unit forces at ``x``."""
    x = np.atleast_1d(np.asarray(x, dtype=float))
    lo, hi = fe.node_x[0], fe.node_x[-1]
    if not np.all(np.isfinite(x)) or np.any(x < lo) or np.any(x > hi):
        raise ValueError(f"x must be finite and within the rail [{lo:g}, {hi:g}] m, got {x!r}")
    e, n = element_shapes(x - lo, fe.element_length, fe.node_x.size - 1, fe.phi)
    g = element_dofs(fe, e).T  # [4, n_x]
    ok = g >= 0
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

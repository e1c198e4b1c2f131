"""Supports that change from sleeper to sleeper: per-sleeper arrays, a void sleeper, scatter.

A :class:`wfjax.Track` carries its five support properties (:data:`SUPPORT_FIELDS`: pad
stiffness and damping, half-sleeper mass, ballast stiffness and damping) either as scalars
(every sleeper alike: Table 2, the default) or as float arrays ``[n_bays - 1]``, one value per
interior sleeper of the finite model, left to right. Sleeper ``i`` (0-based) sits at rail
position ``x = (i + 1 - n_bays // 2) L_S`` (:func:`wfjax.model.sleepers.sleeper_positions`), the
same numbering as
``ModalModel.sleeper_shapes``; the end sleepers under the clamped rail ends are not modelled.

This module builds such tracks: :func:`with_supports` (explicit arrays), :func:`void_sleeper`
(hanging sleepers) and :func:`scatter` (random lognormal scatter from a ``jax.random`` key);
:mod:`wfjax.model.sleepers` reads them (:func:`~wfjax.model.sleepers.support_arrays`,
:func:`~wfjax.model.sleepers.is_uniform`, :func:`~wfjax.model.sleepers.is_mirror_symmetric`). The FE
assembly (:func:`wfjax.model.fe.assemble`) and the modal model
(:func:`wfjax.model.track.modal_model`,
cached per track with the arrays in its key) take the per-sleeper values directly.

A track whose supports vary is not periodic: rail positions are absolute coordinates
(``x = 0`` above the middle sleeper) and the static residual of the modal model is tabulated
along the whole rail (see ``docs/real_track.md``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import jax
import numpy as np

from ..params import SUPPORT_FIELDS, Track
from . import fe as fe_mod
from . import track as track_mod
from .sleepers import check_track, n_sleepers, support_arrays

__all__ = [
    "SUPPORT_FIELDS",
    "with_supports",
    "void_sleeper",
    "hanging_sleeper",
    "hanging_sleepers",
    "OneSidedSupports",
    "one_sided_spec",
    "MAX_ONE_SIDED",
    "scatter",
]

MAX_ONE_SIDED = 8
"""Most hanging (one-sided) sleepers per track: each adds an unknown to every time step."""

SCATTERABLE = SUPPORT_FIELDS[:5]
"""Fields :func:`scatter` may vary (not the ballast gap); their order fixes the draws."""
SCATTER_FIELDS = ("pad_stiffness", "ballast_stiffness")
"""Fields :func:`scatter` varies by default: the two stiffnesses that age and settle."""


def with_supports(track: Track, **fields) -> Track:
    """A copy of ``track`` with the given support fields replaced (scalar or ``[n_bays - 1]``).

    Example: ``with_supports(Track(n_bays=24), ballast_stiffness=kb)`` with ``kb`` [N/m] for
    each of the 23 sleepers.
    Validated as :class:`wfjax.Track` validates (one-line ``ValueError`` naming the field,
    the sleeper index, the value and the allowed range).
    """
    check_track(track)
    bad = [k for k in fields if k not in SUPPORT_FIELDS]
    if bad:
        raise ValueError(f"support fields must be among {SUPPORT_FIELDS}, got {bad!r}")
    return dataclasses.replace(track, **{k: np.asarray(v, dtype=float) if np.ndim(v) else v
                                         for k, v in fields.items()})


def _check_indices(track: Track, index) -> np.ndarray:
    n = n_sleepers(track)
    idx = np.atleast_1d(np.asarray(index))
    if (idx.ndim != 1 or idx.size == 0 or not np.issubdtype(idx.dtype, np.integer)
            or np.any(idx < 0) or np.any(idx >= n)):
        raise ValueError(f"void sleeper index must be an integer (or integers) in [0, {n - 1}] "
                         f"(the n_bays - 1 = {n} modelled sleepers), got {index!r}")
    return idx


def void_sleeper(track: Track, index: int | Sequence[int], remaining: float = 0.0) -> Track:
    """A track with hanging (void) sleepers at ``index``: the ballast support is removed.

    What changes: the ballast stiffness and damping under the sleeper(s) ``index`` (0-based,
    see :func:`wfjax.model.sleepers.sleeper_positions`; the middle sleeper, above ``x = 0``, is
    ``n_bays // 2 - 1``) are multiplied by ``remaining`` (default 0: no support at all).
    Why these: a hanging sleeper is one whose ballast has settled away from it, leaving a
    gap under it; it stays fastened to the rail, so its pad and its mass are kept and the
    sleeper's mass now hangs from the rail. The support is linear: the limit of a void deeper
    than the rail's deflection over it (a gap that closes under the wheel load:
    :func:`hanging_sleeper`; default track, 118 kN above the sleeper: 1.67 mm over
    one void against 0.87 mm over a supported sleeper).

    Args:
        track: the track to start from (uniform or not).
        index: one sleeper index or several (e.g. ``[33, 34]``), each in ``[0, n_bays - 2]``.
        remaining: fraction of the ballast stiffness and damping left, in ``[0, 1]``.

    Returns:
        a new :class:`wfjax.Track` with per-sleeper ballast arrays.
    """
    idx = _check_indices(track, index)
    try:
        frac = float(remaining)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"remaining must be a fraction in [0, 1], got {remaining!r}") from exc
    if not 0.0 <= frac <= 1.0:
        raise ValueError(f"remaining must be a fraction in [0, 1], got {remaining!r}")
    arrays = support_arrays(track)
    kb, cb = arrays["ballast_stiffness"], arrays["ballast_damping"]
    kb[idx] *= frac
    cb[idx] *= frac
    return with_supports(track, ballast_stiffness=kb, ballast_damping=cb)


def hanging_sleeper(track: Track, index: int | Sequence[int], gap: float) -> Track:
    """A track whose sleeper(s) ``index`` hang ``gap`` [m] above their ballast: one-sided.

    The ballast (its ``k_B`` and ``c_B`` at that sleeper) carries no load until the sleeper
    has moved down by ``gap``, then pushes back, in compression only: the support force
    F = max(0, k_B e + c_B de/dt) for the closure e = u_sleeper - gap > 0, else 0 (no
    tension; e/dt from the step's change of max(e, 0), so the force rises continuously
    from 0 when the gap closes). The linear track model is the open one (no ballast
    there, as :func:`void_sleeper`); the support is solved in every time step together with
    the wheel contacts (``docs/real_track.md``). A deep gap that never closes gives
    :func:`void_sleeper`'s results; ``gap`` = 0 a sleeper that rests on its ballast but
    can lift off it.

    Args:
        track: the track to start from. index: sleeper index or indices in
            ``[0, n_bays - 2]`` (:func:`wfjax.model.sleepers.sleeper_positions`). gap: g [m] in
            [0, 0.05] (one value for all, or one per index).

    Returns:
        a new :class:`wfjax.Track` with a per-sleeper ``ballast_gap`` array.
    """
    idx = _check_indices(track, index)
    gaps = np.broadcast_to(np.asarray(gap, dtype=float), idx.shape) if np.ndim(gap) == 0 \
        else np.asarray(gap, dtype=float)
    if gaps.shape != idx.shape:
        raise ValueError(f"gap must be one value or one per sleeper index ({idx.size}), got "
                         f"shape {gaps.shape}")
    arr = support_arrays(track)["ballast_gap"]
    arr[idx] = gaps
    out = with_supports(track, ballast_gap=arr)
    hanging_sleepers(out)  # refuses too many
    return out


def hanging_sleepers(track: Track) -> np.ndarray:
    """Indices (int [n_s]) of the sleepers with a one-sided ballast (``ballast_gap > 0``).

    Raises ValueError for more than :data:`MAX_ONE_SIDED` of them or a scalar gap > 0."""
    if np.ndim(track.ballast_gap) == 0 and float(track.ballast_gap) > 0:
        raise ValueError("Track.ballast_gap > 0 must be given per sleeper (hanging_sleeper), "
                         f"not as one value for every sleeper: got {track.ballast_gap!r}")
    idx = np.flatnonzero(support_arrays(track)["ballast_gap"] > 0)
    if idx.size > MAX_ONE_SIDED:
        raise ValueError(f"at most {MAX_ONE_SIDED} hanging sleepers (ballast_gap > 0) per "
                         f"track, got {idx.size}: each is an unknown of every time step")
    return idx


class OneSidedSupports(NamedTuple):
    """The one-sided ballast supports of a track, as the time loop reads them (arrays).

    ``shapes`` complex [n_s, n_modes]: the modes at the sleepers' DOFs
    (``ModalModel.sleeper_shapes``); ``gap`` [n_s] m; ``stiffness`` [n_s] N/m; ``damping``
    [n_s] N s/m; ``residual`` [n_s, n_s] m/N: static compliance of the truncated modes between
    the sleepers; ``residual_wheels`` [n_res, n_w, n_s] m/N: the same between the wheels (the
    reference wheel on the residual grid, read by :func:`wfjax.model.track.read_residual_table`) and
    the sleepers. Displacements are downwards, the support forces upwards on the sleepers.
    """

    shapes: Any
    gap: Any
    stiffness: Any
    damping: Any
    residual: Any
    residual_wheels: Any


def one_sided_spec(track: Track, model, offsets=(0.0,)) -> OneSidedSupports | None:
    """:class:`OneSidedSupports` of ``track`` for wheels at ``offsets`` [n_w] [m] behind the
    reference wheel, from its modal model ``model`` (None when no sleeper hangs)."""
    idx = hanging_sleepers(track)
    if idx.size == 0:
        return None
    arrays = support_arrays(track)
    fe = fe_mod.assemble(track)
    # an absorbing end's grading holds for the one-sided ballast too (as in fe.assemble)
    grading = fe_mod.end_grading(arrays["ballast_damping"].size, int(track.absorbing_sleepers))
    unit = np.zeros((fe.stiffness.shape[0], idx.size))
    unit[fe.n_rail_dof + idx, np.arange(idx.size)] = 1.0  # unit loads on the sleepers
    k_inv_s = fe_mod.static_solve(fe, unit)  # [n_dof, n_s]
    psi = np.asarray(model.sleeper_shapes)[:, idx].T  # [n_s, m]
    w = np.asarray(model.weights) / (-np.asarray(model.poles))
    kept_ss = np.real(np.einsum("am,bm,m->ab", psi, psi, w))
    offsets = np.atleast_1d(np.asarray(offsets, dtype=float))
    x = np.asarray(model.residual_x)[:, None] + offsets[None, :]  # the whole-rail grid
    x = np.clip(x, fe.node_x[0], fe.node_x[-1])
    b = fe_mod.load_vector(fe, x.ravel())  # [n_dof, n_res * n_w]
    full_ws = np.asarray(b.T @ k_inv_s).reshape(*x.shape, idx.size)
    phi = np.asarray(track_mod.mode_shapes_at(model, x))  # [n_res, n_w, m]
    kept_ws = np.real(np.einsum("rim,am,m->ria", phi, psi, w))
    return OneSidedSupports(psi, arrays["ballast_gap"][idx], arrays["ballast_stiffness"][idx],
                            (arrays["ballast_damping"] * grading)[idx], unit.T @ k_inv_s - kept_ss,
                            full_ws - kept_ws)


def as_key(key) -> jax.Array:
    """A ``jax.random`` key from a key (returned as is) or an integer seed (``PRNGKey``)."""
    if isinstance(key, (int, np.integer)) and not isinstance(key, bool):
        return jax.random.PRNGKey(int(key))
    if not hasattr(key, "dtype") or isinstance(key, np.ndarray) and key.dtype.kind == "f":
        raise ValueError(f"key must be a jax.random key or an integer seed, got {key!r}")
    return key


def scatter(track: Track, key, cv: float | Mapping[str, float] = 0.3,
            fields: Sequence[str] = SCATTER_FIELDS) -> Track:
    """Random lognormal scatter of the supports, independent from sleeper to sleeper.

    Each value ``v_i`` of a scattered field becomes ``v_i * exp(sigma z_i - sigma^2 / 2)`` with
    ``z_i`` standard normal and ``sigma^2 = ln(1 + cv^2)``: lognormal with the mean ``v_i`` and
    coefficient of variation ``cv`` (standard deviation / mean). Fields are drawn from
    independent subkeys of ``key``, in :data:`SCATTERABLE` order, so a field's draw does
    not depend on which other fields are scattered.

    Args:
        track: the track to start from (its values are the means).
        key: a ``jax.random`` key, or an integer seed (``jax.random.PRNGKey(seed)``).
        cv: coefficient of variation (>= 0, at most 2), one for all ``fields`` or a mapping
            ``{field: cv}`` (then ``fields`` is ignored).
        fields: support fields to scatter (default pad and ballast stiffness).

    Returns:
        a new :class:`wfjax.Track` with per-sleeper arrays for the scattered fields.
    """
    check_track(track)
    cvs = dict(cv) if isinstance(cv, Mapping) else {f: cv for f in fields}
    bad = [k for k in cvs if k not in SCATTERABLE]
    if bad or not cvs:
        raise ValueError(f"scattered fields must be among {SCATTERABLE}, got {list(cvs)!r}")
    for name, c in cvs.items():
        try:
            c = float(c)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"cv of {name} must be a number in [0, 2], got {c!r}") from exc
        if not 0.0 <= c <= 2.0:
            raise ValueError(f"cv of {name} must be in [0, 2] (coefficient of variation), "
                             f"got {c!r}")
        cvs[name] = c
    key = as_key(key)
    subkeys = jax.random.split(key, len(SCATTERABLE))
    arrays = support_arrays(track)
    n = n_sleepers(track)
    out = {}
    for i, name in enumerate(SCATTERABLE):
        if name not in cvs:
            continue
        sigma = math.sqrt(math.log1p(cvs[name] ** 2))
        z = np.asarray(jax.random.normal(subkeys[i], (n,), dtype=np.float64))
        out[name] = arrays[name] * np.exp(sigma * z - sigma**2 / 2)
    return with_supports(track, **out)

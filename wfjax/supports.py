"""Supports that change from sleeper to sleeper: per-sleeper arrays, a void sleeper, scatter.

A :class:`wfjax.Track` carries its five support properties (:data:`SUPPORT_FIELDS`: pad
stiffness and damping, half-sleeper mass, ballast stiffness and damping) either as scalars
(every sleeper alike: Table 2, the default) or as float arrays ``[n_bays - 1]``, one value per
interior sleeper of the finite model, left to right. Sleeper ``i`` (0-based) sits at rail
position ``x = (i + 1 - n_bays // 2) L_S`` (:func:`sleeper_positions`), the same numbering as
``ModalModel.sleeper_shapes``; the end sleepers under the clamped rail ends are not modelled.

This module builds such tracks: :func:`with_supports` (explicit arrays), :func:`void_sleeper`
(hanging sleepers) and :func:`scatter` (random lognormal scatter from a ``jax.random`` key);
:func:`support_arrays`, :func:`is_uniform` and :func:`is_mirror_symmetric` read them. The FE
assembly (:func:`wfjax.track.assemble`) and the modal model (:func:`wfjax.track.modal_model`,
cached per track with the arrays in its key) take the per-sleeper values directly.

A track whose supports vary is not periodic: rail positions are absolute coordinates
(``x = 0`` above the middle sleeper) and the static residual of the modal model is tabulated
along the whole rail (see ``docs/real_track.md``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import jax
import numpy as np

from .params import SUPPORT_FIELDS, Track

__all__ = [
    "SUPPORT_FIELDS",
    "n_sleepers",
    "sleeper_positions",
    "sleeper_index",
    "support_arrays",
    "is_uniform",
    "is_mirror_symmetric",
    "with_supports",
    "void_sleeper",
    "scatter",
]

SCATTER_FIELDS = ("pad_stiffness", "ballast_stiffness")
"""Fields :func:`scatter` varies by default: the two stiffnesses that age and settle."""


def _check_track(track) -> Track:
    if not isinstance(track, Track):
        raise ValueError(f"track must be a wfjax.Track, got {type(track).__name__}")
    return track


def n_sleepers(track: Track) -> int:
    """Number of modelled (interior) sleepers, ``n_bays - 1``."""
    return int(_check_track(track).n_bays) - 1


def sleeper_positions(track: Track) -> np.ndarray:
    """Rail positions [m] of the modelled sleepers, float ``[n_bays - 1]``, left to right."""
    nb = int(_check_track(track).n_bays)
    return (np.arange(nb - 1) + 1 - nb // 2) * float(track.sleeper_spacing)


def sleeper_index(track: Track, x: float) -> int:
    """Index of the modelled sleeper nearest to rail position ``x`` [m].

    Raises ``ValueError`` if ``x`` is not finite or no modelled sleeper is within half a bay.
    """
    pos = sleeper_positions(track)
    ls = float(track.sleeper_spacing)
    try:
        xv = float(x)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"x must be a rail position in m, got {x!r}") from exc
    if not math.isfinite(xv) or xv < pos[0] - ls / 2 or xv > pos[-1] + ls / 2:
        raise ValueError(f"x must be within [{pos[0] - ls / 2:g}, {pos[-1] + ls / 2:g}] m "
                         f"(the modelled sleepers), got {x!r}")
    return int(np.argmin(np.abs(pos - xv)))


def support_arrays(track: Track) -> dict[str, np.ndarray]:
    """The five support properties per sleeper: ``{field: float [n_bays - 1]}`` (SI units).

    Scalars are broadcast; the values are concrete numbers (checked when the track was made).
    """
    n = n_sleepers(track)
    out = {}
    for name in SUPPORT_FIELDS:
        raw = getattr(track, name)
        try:
            arr = np.asarray(raw, dtype=float)
        except (TypeError, jax.errors.ConcretizationTypeError) as exc:
            raise ValueError(f"Track.{name} must be concrete numbers here, got {raw!r}") from exc
        out[name] = np.array(np.broadcast_to(arr, (n,)))
    return out


def is_uniform(track: Track) -> bool:
    """True when every sleeper has the same supports (scalars, or constant arrays)."""
    return all(np.all(a == a[0]) for a in support_arrays(track).values())


def is_mirror_symmetric(track: Track) -> bool:
    """True when the supports are mirror symmetric about the middle sleeper (``x = 0``).

    Needs an even ``n_bays`` (then the middle sleeper is a modelled one and the clamped track
    is symmetric); the modal model then splits into symmetric and antisymmetric halves.
    """
    if int(_check_track(track).n_bays) % 2:
        return False
    return all(np.array_equal(a, a[::-1]) for a in support_arrays(track).values())


def with_supports(track: Track, **fields) -> Track:
    """A copy of ``track`` with the given support fields replaced (scalar or ``[n_bays - 1]``).

    Example: ``with_supports(Track(), ballast_stiffness=kb)`` with ``kb`` [N/m] per sleeper.
    Validated as :class:`wfjax.Track` validates (one-line ``ValueError`` naming the field,
    the sleeper index, the value and the allowed range).
    """
    _check_track(track)
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
    see :func:`sleeper_positions`; the middle sleeper, above ``x = 0``, is
    ``n_bays // 2 - 1``) are multiplied by ``remaining`` (default 0: no support at all).
    Why these: a hanging sleeper is one whose ballast has settled away from it, leaving a
    gap under it; it stays fastened to the rail, so its pad and its mass are kept and the
    sleeper's mass now hangs from the rail. The support is linear: a gap that closes under the
    wheel load (a one-sided contact) is not modelled, so this is the limit of a void deeper
    than the rail's deflection over it (default track, 118 kN above the sleeper: 1.67 mm over
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
    independent subkeys of ``key``, in :data:`SUPPORT_FIELDS` order, so a field's draw does
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
    _check_track(track)
    cvs = dict(cv) if isinstance(cv, Mapping) else {f: cv for f in fields}
    bad = [k for k in cvs if k not in SUPPORT_FIELDS]
    if bad or not cvs:
        raise ValueError(f"scattered fields must be among {SUPPORT_FIELDS}, got {list(cvs)!r}")
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
    subkeys = jax.random.split(key, len(SUPPORT_FIELDS))
    arrays = support_arrays(track)
    n = n_sleepers(track)
    out = {}
    for i, name in enumerate(SUPPORT_FIELDS):
        if name not in cvs:
            continue
        sigma = math.sqrt(math.log1p(cvs[name] ** 2))
        z = np.asarray(jax.random.normal(subkeys[i], (n,), dtype=np.float64))
        out[name] = arrays[name] * np.exp(sigma * z - sigma**2 / 2)
    return with_supports(track, **out)

"""The sleepers of a track and their supports, read: count, positions, per-sleeper arrays.

A :class:`wfjax.Track` carries its five support properties (:data:`SUPPORT_FIELDS`) as scalars
or as arrays ``[n_bays - 1]``, one value per interior sleeper of the finite model (see
:mod:`wfjax.model.supports`, which builds such tracks).
Sleeper ``i`` (0-based) sits at rail position
``x = (i + 1 - n_bays // 2) L_S`` (:func:`sleeper_positions`). The FE assembly and the modal
model (:mod:`wfjax.model.track`) read the supports through :func:`support_arrays`,
:func:`is_uniform` and :func:`is_mirror_symmetric`; this module imports no other of wfjax's
models, so both :mod:`wfjax.model.track` and :mod:`wfjax.model.supports` build on it.
"""

from __future__ import annotations

import math

import jax
import numpy as np

from ..params import SUPPORT_FIELDS, Track

__all__ = [
    "check_track",
    "n_sleepers",
    "sleeper_positions",
    "sleeper_index",
    "support_arrays",
    "is_uniform",
    "is_mirror_symmetric",
]


def check_track(track) -> Track:
    """``track`` if it is a :class:`wfjax.Track`, else a one-line ``ValueError``."""
    if not isinstance(track, Track):
        raise ValueError(f"track must be a wfjax.Track, got {type(track).__name__}")
    return track


def n_sleepers(track: Track) -> int:
    """Number of modelled (interior) sleepers, ``n_bays - 1``."""
    return int(check_track(track).n_bays) - 1


def sleeper_positions(track: Track) -> np.ndarray:
    """Rail positions [m] of the modelled sleepers, float ``[n_bays - 1]``, left to right."""
    nb = int(check_track(track).n_bays)
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


def is_periodic(track: Track) -> bool:
    """True when the track repeats bay by bay as a linear model: every sleeper the same
    supports (:func:`is_uniform`) and none hanging (``ballast_gap`` 0), so that it has an
    infinite periodic and a semi-infinite continuation (:mod:`wfjax.model.periodic`,
    :mod:`wfjax.model.ends`)."""
    return is_uniform(track) and not np.any(np.asarray(track.ballast_gap, dtype=float) > 0)


def is_mirror_symmetric(track: Track) -> bool:
    """True when the supports are mirror symmetric about the middle sleeper (``x = 0``).

    Needs an even ``n_bays`` (then the middle sleeper is a modelled one and the clamped track
    is symmetric); the modal model then splits into symmetric and antisymmetric halves.
    """
    if int(check_track(track).n_bays) % 2:
        return False
    return all(np.array_equal(a, a[::-1]) for a in support_arrays(track).values())

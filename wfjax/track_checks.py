"""Checks of a :class:`wfjax.Track`'s supports and ends, one-line errors: per-sleeper support
arrays (length, finiteness, sign) and the end networks' conditions."""

from __future__ import annotations

from typing import Any

import numpy as np

from .fields import is_concrete

_ZERO_ALLOWED = ("pad_damping", "ballast_stiffness", "ballast_damping", "ballast_gap")
MAX_BALLAST_GAP = 0.05  # m: a void deeper than 50 mm under a sleeper is a data error


def check_per_sleeper(name: str, value: Any, unit: str, n_sleepers: int) -> None:
    """Check one per-sleeper support array: length, finiteness, sign (one-line errors)."""
    arr = np.asarray(value, dtype=float)
    if arr.shape != (n_sleepers,):
        raise ValueError(
            f"Track.{name} must be a scalar or an array of n_bays - 1 = {n_sleepers} values "
            f"(one per interior sleeper), got shape {arr.shape}"
        )
    zero_ok = name in _ZERO_ALLOWED
    bad = ~np.isfinite(arr) | ((arr < 0) if zero_ok else (arr <= 0))
    if name == "ballast_gap":
        bad |= arr > MAX_BALLAST_GAP
        unit = f"m, at most {MAX_BALLAST_GAP}"
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        rng = f"[0, inf) {unit}" if zero_ok else f"(0, inf) {unit}"
        raise ValueError(
            f"Track.{name}[{i}] must be finite and {'>=' if zero_ok else '>'} 0 {unit}, got "
            f"{arr[i]!r} (allowed range: {rng})"
        )


def check_ends(track, support_fields, allowed) -> None:
    """``Track.ends``: one of ``allowed``; ``"network"`` on supports that are the same at
    every sleeper (``support_fields``: the fields that may vary)."""
    if track.ends not in allowed:
        raise ValueError(f"Track.ends must be one of {allowed}, got {track.ends!r}")
    if track.ends != "network":
        return
    varying = [n for n in support_fields if is_concrete(getattr(track, n))
               and np.ndim(getattr(track, n)) and np.ptp(getattr(track, n))]
    if varying:
        raise ValueError(f"Track.ends='network' needs the same supports at every sleeper (a "
                         f"per-sleeper {varying[0]} has no semi-infinite continuation to "
                         f"fit): use ends='absorbing'")

"""The measured data a fit takes: :class:`MaxForceData`, :class:`HistoryData`,
:class:`DetectorData`, and their checks."""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from ..scenario.windows import check_speed, check_speeds

__all__ = ["MaxForceData", "HistoryData", "DetectorData", "validate_data"]

MIN_POINTS_MAX_FORCE = 3
MIN_POINTS_HISTORY = 10


# -- measured data ------------------------------------------------------------------------
class MaxForceData(NamedTuple):
    """Maximum impact force against speed (a wheel impact load detector).

    Attributes:
        speeds: [n] train speeds [m/s], > 0.
        max_force: [n] measured maximum contact force [N] at each speed.
    """

    speeds: Any
    max_force: Any


class HistoryData(NamedTuple):
    """A contact-force time history at one speed.

    Attributes:
        t: [n] strictly increasing times [s], t = 0 when the flat centre is over the nominal
            contact point.
        force: [n] measured contact force [N].
        speed: train speed [m/s].
        impact_position: rail coordinate [m] of the impact within the sleeper bay [0, L_S).
    """

    t: Any
    force: Any
    speed: float
    impact_position: float = 0.0


class DetectorData(NamedTuple):
    """Wheel impact load detector readings against speed.

    Attributes:
        speeds: [n] train speeds [m/s], > 0.
        peak: [n] the maximum over the detector's bays of each passage's reading [N], or
            [n, n_bays] the reading of every bay [N] (then ``impact_position`` is needed).
        detector: the :class:`wfjax.Detector` (default ``Detector()``: 3 bays).
        impact_position: rail coordinate [m] of the impact in [0, L_S) for per-bay data
            (None for max-over-bays data: the model takes a smooth max over positions).
    """

    speeds: Any
    peak: Any
    detector: Any = None
    impact_position: float | None = None


def _finite_1d(name: str, value) -> np.ndarray:
    a = np.asarray(value, dtype=float)
    if a.ndim != 1:
        raise ValueError(f"{name} must be a 1-D array, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains NaN or infinite values: {a!r}")
    return a


def _check_data_speeds(v: np.ndarray, n_params: int, what: str) -> None:
    """Enough speeds [m/s], checked by :func:`check_speeds`, for ``n_params`` parameters of
    ``what`` data."""
    need = max(MIN_POINTS_MAX_FORCE, n_params + 1)
    if v.size < need:
        raise ValueError(f"{what} data needs at least {need} speeds to fit {n_params} "
                         f"parameter(s), got {v.size}")
    check_speeds(v)


def validate_data(measured, n_params: int):
    """Check ``measured`` and return it as :class:`MaxForceData` or :class:`HistoryData`."""
    if isinstance(measured, dict):
        if "peak" in measured:
            measured = DetectorData(**measured)
        elif "t" in measured:
            measured = HistoryData(**measured)
        else:
            measured = MaxForceData(**measured)
    if isinstance(measured, MaxForceData):
        v = _finite_1d("speeds", measured.speeds)
        f = _finite_1d("max_force", measured.max_force)
        if f.shape != v.shape:
            raise ValueError(f"speeds and max_force must have equal length, got {v.size} and "
                             f"{f.size}")
        _check_data_speeds(v, n_params, "max-force")
        if np.any(f <= 0):
            raise ValueError(f"max_force must be > 0 N, got min {f.min():.6g} N")
        return MaxForceData(v, f)
    if isinstance(measured, DetectorData):
        from ..scenario.sensors import Detector

        v = _finite_1d("speeds", measured.speeds)
        peak = np.asarray(measured.peak, dtype=float)
        det = measured.detector or Detector()
        if not isinstance(det, Detector):
            raise ValueError(f"detector must be a wfjax.Detector, got {det!r}")
        if peak.ndim == 2 and peak.shape != (v.size, det.n_bays):
            raise ValueError(f"per-bay peak must be [n_speeds, n_bays] = [{v.size}, "
                             f"{det.n_bays}], got {peak.shape}")
        if peak.ndim not in (1, 2) or peak.shape[0] != v.size:
            raise ValueError(f"peak must be [n_speeds] or [n_speeds, n_bays] with n_speeds = "
                             f"{v.size}, got shape {peak.shape}")
        if not np.all(np.isfinite(peak)) or np.any(peak <= 0):
            raise ValueError("peak readings must be finite and > 0 N")
        _check_data_speeds(v, n_params, "detector")
        if peak.ndim == 2 and measured.impact_position is None:
            raise ValueError("per-bay detector data needs impact_position [m]")
        return DetectorData(v, peak, det, measured.impact_position)
    if isinstance(measured, HistoryData):
        t = _finite_1d("t", measured.t)
        f = _finite_1d("force", measured.force)
        if f.shape != t.shape:
            raise ValueError(f"t and force must have equal length, got {t.size} and {f.size}")
        if t.size < max(MIN_POINTS_HISTORY, n_params + 1):
            raise ValueError(f"a force history needs at least {MIN_POINTS_HISTORY} samples, "
                             f"got {t.size}")
        if np.any(np.diff(t) <= 0):
            raise ValueError("t must be strictly increasing")
        if np.any(f < 0):
            raise ValueError(f"force must be >= 0 N, got min {f.min():.6g} N")
        speed = check_speed(measured.speed)
        pos = float(measured.impact_position)
        if not math.isfinite(pos):
            raise ValueError(f"impact_position must be finite, got {measured.impact_position!r}")
        return HistoryData(t, f, speed, pos)
    raise ValueError(f"measured must be MaxForceData, HistoryData, DetectorData or a dict, got "
                     f"{type(measured).__name__}")

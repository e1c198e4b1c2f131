"""A run's window along the rail and the checks of where and how fast it runs.

Every entry point (:func:`wfjax.simulate`, :func:`wfjax.sweep`, the fits' force models) takes
its windows, step counts and impact-position and speed checks from here, once.

Impact position
---------------
``impact_position`` is the rail coordinate [m] (measured from a sleeper centre, within one bay
[0, L_S)) where the flat centre meets the nominal contact point. The paper instead varies the
initial angular position of the wheel, ``angle0`` [rad]: with the wheel starting at rail
coordinate X_0 with the flat centre at angle ``angle0`` ahead of the contact point (rolling
direction), the flat reaches the contact after rolling R * angle0, so
impact_position = (X_0 + R * angle0) mod L_S. :func:`impact_position_from_angle` does that.
On a track whose supports vary (:func:`wfjax.model.sleepers.is_uniform` false) every bay differs and
``impact_position`` is an absolute rail coordinate (x = 0 above the middle sleeper;
``docs/real_track.md``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..contact.laws import FLAT_MARGIN
from ..model.sleepers import is_uniform
from ..model.vehicle import placement
from ..params import MAX_SPEED, Flat, SimConfig, Track

__all__ = ["RUN_IN_TIME", "RUN_OUT_TIME", "impact_position_from_angle", "simulation_window",
           "check_speed", "check_speeds", "check_impact_position", "check_impact_positions",
           "impact_positions_grid", "n_steps_for", "run_windows", "batch_windows",
           "check_rail_span", "wheel_positions", "vehicle_window_flat", "detector_config"]

RUN_IN_TIME = 0.02  # s of travel before the flat's window, from static equilibrium


RUN_OUT_TIME = 0.03  # s after the flat's window: loss of contact and re-impacts


def impact_position_from_angle(angle0, start_position: float = 0.0, wheel_radius: float = 0.45,
                               sleeper_spacing: float = 0.65):
    """Impact position [m] within the bay from the paper's initial angular wheel position.

    Args:
        angle0: angle [rad] by which the flat centre is ahead of the contact point (in the
            rolling direction) when the wheel is at rail coordinate ``start_position`` [m].
        start_position: initial rail coordinate of the nominal contact point [m].
        wheel_radius: R_W [m]. sleeper_spacing: L_S [m].

    Returns:
        (start_position + R angle0) mod L_S [m].
    """
    return np.mod(start_position + wheel_radius * np.asarray(angle0), sleeper_spacing)


def simulation_window(flat: Flat, speed: float, config: SimConfig) -> tuple[float, float]:
    """(s_start, s_end) [m]: wheel positions relative to the impact where the run starts/ends.

    Run-in ``RUN_IN_TIME`` s of travel before the flat's window (half extent + 20 mm), and
    ``RUN_OUT_TIME`` s after it, or ``config.run_in``/``config.run_out`` m if longer.
    """
    half = flat.half_extent + FLAT_MARGIN
    run_in = max(config.run_in, RUN_IN_TIME * speed)
    run_out = max(config.run_out, RUN_OUT_TIME * speed)
    return -(half + run_in), half + run_out


def check_speeds(speeds, name: str = "speeds") -> np.ndarray:
    """``speeds`` [n] [m/s] as a non-empty 1-D array in (0, :data:`MAX_SPEED`]; a one-line
    ``ValueError`` naming ``name`` otherwise."""
    v = np.atleast_1d(np.asarray(speeds, dtype=float))
    if (v.ndim != 1 or v.size == 0 or not np.all(np.isfinite(v)) or np.any(v <= 0)
            or np.any(v > MAX_SPEED)):
        raise ValueError(f"{name} must be a non-empty 1-D array in (0, {MAX_SPEED:g}] m/s "
                         f"(0-{MAX_SPEED * 3.6:g} km/h), got {speeds!r}")
    return v


def check_speed(speed) -> float:
    """One speed [m/s] checked as :func:`check_speeds` does."""
    if np.ndim(speed) != 0:
        raise ValueError(f"speed must be one number [m/s], got {speed!r}")
    return float(check_speeds(speed, "speed")[0])


def impact_positions_grid(n: int, sleeper_spacing: float = 0.65) -> np.ndarray:
    """``n`` impact positions [m] evenly covering one bay: (k + 0.5) L_S / n."""
    if int(n) != n or n < 1:
        raise ValueError(f"impact_positions must be a positive integer or an array, got {n!r}")
    return (np.arange(int(n)) + 0.5) * sleeper_spacing / int(n)


def check_impact_positions(positions, track: Track, name: str = "impact_positions"
                           ) -> np.ndarray:
    """``positions`` [n] [m] checked for ``track``: within one bay, ``[0, L_S)``, on a uniform
    track; absolute rail coordinates (x = 0 above the middle sleeper) within
    ``|x| <= (n_bays // 2 - 1) L_S`` when the supports vary
    (:func:`wfjax.model.sleepers.is_uniform`:
    every bay differs, so the impact's bay matters). One-line ``ValueError`` naming ``name``
    otherwise."""
    pos = np.atleast_1d(np.asarray(positions, dtype=float))
    spacing = float(track.sleeper_spacing)
    if pos.ndim != 1 or pos.size == 0 or not np.all(np.isfinite(pos)):
        raise ValueError(f"{name} must be a 1-D array of finite numbers [m], got {positions!r}")
    if is_uniform(track):
        if np.any(pos < 0) or np.any(pos >= spacing):
            raise ValueError(f"{name} must lie in [0, {spacing:g}) m (within one sleeper bay), "
                             f"got {positions!r}")
        return pos
    reach = (int(track.n_bays) // 2 - 1) * spacing
    if np.any(np.abs(pos) > reach):
        raise ValueError(f"{name} on a track whose supports vary are absolute rail "
                         f"coordinates within [-{reach:g}, {reach:g}] m, got {positions!r}")
    return pos


def check_impact_position(position, track: Track) -> float:
    """One impact position [m] checked as :func:`check_impact_positions` does."""
    if np.ndim(position) != 0:
        raise ValueError(f"impact_position must be one number [m], got {position!r}")
    return float(check_impact_positions(position, track, "impact_position")[0])


def n_steps_for(flat: Flat, speed: float, config: SimConfig) -> tuple[int, float]:
    """(number of steps, time step [s]) of a simulation at ``speed`` [m/s]."""
    s0, s1 = simulation_window(flat, speed, config)
    duration = (s1 - s0) / speed
    dt = config.time_step_for(speed)
    n = int(math.ceil(duration / dt)) + 1
    return n, duration / (n - 1)


def run_windows(flat: Flat, speeds, config: SimConfig):
    """Every speed's own window, as :func:`simulate` runs it (:func:`n_steps_for`).

    Returns:
        (n_steps [n_speeds] int, dt [n_speeds] s, s_start [n_speeds] m, run_in [n_speeds]
        steps before the max/min summaries start).
    """
    speeds = np.asarray(speeds, dtype=float)
    n_steps, dt = (np.array(a) for a in zip(*(n_steps_for(flat, float(v), config)
                                              for v in speeds), strict=True))
    s0 = np.array([simulation_window(flat, float(v), config)[0] for v in speeds])
    return n_steps.astype(int), dt, s0, np.floor(0.5 * RUN_IN_TIME / dt).astype(int)


def batch_windows(flat: Flat, speeds, config: SimConfig):
    """Windows of a batch of runs at ``speeds`` [m/s] that share one compiled step count.

    Every speed gets the step count of the one that needs the most and its own time step.

    Returns:
        (n_steps, dt [n_speeds] s, s_start [n_speeds] m, run_in [n_speeds] steps before the
        max/min summaries start).
    """
    speeds = np.asarray(speeds, dtype=float)
    n_steps = max(n_steps_for(flat, float(v), config)[0] for v in speeds)
    s0, s1 = np.array([simulation_window(flat, float(v), config) for v in speeds]).T
    dt = (s1 - s0) / speeds / (n_steps - 1)
    return n_steps, dt, s0, np.floor(0.5 * RUN_IN_TIME / dt).astype(int)


def check_rail_span(rail, x_lo: float, x_hi: float) -> None:
    """One-line ``ValueError`` unless the rail roughness ``rail`` (or None) covers every
    contact position of the run, ``[x_lo, x_hi]`` [m] (a profile holds its end values
    beyond its span: the run would see a constant there)."""
    if rail is None:
        return
    x0 = float(np.asarray(rail.x_start))
    x1 = x0 + float(np.asarray(rail.spacing)) * (np.shape(rail.values)[-1] - 1)
    if x_lo < x0 - 1e-9 or x_hi > x1 + 1e-9:
        raise ValueError(f"roughness covers x in [{x0:.4g}, {x1:.4g}] m but the run's contacts "
                         f"reach [{x_lo:.4g}, {x_hi:.4g}] m: give a profile over at least that "
                         f"span (x_start, length)")


def wheel_positions(vehicle, sleeper_spacing: float) -> tuple:
    """Every wheel's rail coordinate at the reference impact, less the impact position [m]."""
    shift = placement(vehicle, sleeper_spacing)
    return tuple(float(shift + o) for o in vehicle.offsets())


def vehicle_window_flat(vehicle, flats: list[Flat]) -> Flat:
    """The flat whose simulation window covers every flat of the vehicle.

    Every wheel's flat must pass its contact within the window: a flat delayed by d [m]
    needs the reference window widened by |d| on that side, which a flat of half extent
    max_i(half_i + |d_i|) gives (an ``extent_bound`` on the reference flat; its geometry is
    unchanged).
    """
    delays = vehicle.delays()
    reach = max(float(f.half_extent) + abs(d) for f, d in zip(flats, delays, strict=True)
                if f.kind != "none" or f is flats[vehicle.flat_wheel])
    ref = flats[vehicle.flat_wheel]
    if reach <= float(ref.half_extent):
        return ref
    return dataclasses.replace(ref, extent_bound=reach)


def detector_config(detector, track: Track, config: SimConfig,
                    wheel_positions=(0.0,)) -> SimConfig:
    """``config`` with ``run_in``/``run_out`` [m] long enough for every wheel to cross every
    bay of ``detector`` (for any impact position in [0, L_S) and any flat; 5 cm margin).

    ``wheel_positions``: [n] every wheel's rail coordinate at the reference impact, less the
    impact position [m] (a vehicle: its placement plus the wheels' offsets; one wheel: 0).
    """
    a, b = detector.gauges(float(track.sleeper_spacing))
    run_in = max(wheel_positions) + float(track.sleeper_spacing) - float(a[0]) + 0.05
    run_out = float(b[-1]) - min(wheel_positions) + 0.05
    return dataclasses.replace(config, run_in=max(config.run_in, run_in),
                               run_out=max(config.run_out, run_out))

"""Predicted size of a run's output files, checked before any computation.

The estimates are upper bounds from the shapes of the results (``docs/case_files.md``,
"Limits"): a CSV number takes at most :data:`CSV_BYTES` bytes (``%.9g``, a sign, an exponent
and the comma), an NPZ number 8 bytes. Above :data:`wfjax.limits.MAX_OUTPUT_BYTES` (1 GB) a
run is refused unless ``--allow-large-output`` (``run.allow_large_output = true``).
"""

from __future__ import annotations

import math

from .limits import check_output_size
from .scenario.sensors import QUANTITIES
from .scenario.windows import simulation_window

__all__ = ["CSV_BYTES", "simulate_bytes", "sweep_bytes", "check_simulate", "check_sweep",
           "check_detector"]

CSV_BYTES = 17  # bytes per CSV number: "-1.23456789e-05," and a little
FIGURES_BYTES = 2_000_000  # the PNG figures and the JSON summary of one run, at most


def n_steps(flat, speed: float, config) -> int:
    """Time steps of one run of ``flat`` at ``speed`` [m/s] under ``config``."""
    s0, s1 = simulation_window(flat, speed, config)
    dt = config.time_step_for(speed)
    return int(math.ceil((s1 - s0) / (speed * dt))) + 1


def simulate_bytes(steps: int, n_sensors: int = 0, n_wheels: int = 1,
                   n_hanging: int = 0) -> float:
    """Bytes of ``simulate``'s files: ``simulate.csv`` (8 columns, 2 per wheel of a vehicle,
    2 per hanging sleeper) and ``sensors.csv`` (2 + one per quantity and sensor) over
    ``steps`` time steps."""
    wheels = 2 * n_wheels if n_wheels > 1 else 0
    columns = 8 + wheels + 2 * n_hanging
    if n_sensors:
        columns += 2 + len(QUANTITIES) * n_sensors
    return steps * columns * CSV_BYTES + FIGURES_BYTES


def sweep_bytes(n_flats: int, n_speeds: int, n_positions: int, n_wheels: int = 1,
                n_realisations: int = 1, n_sensors: int = 0) -> float:
    """Bytes of ``sweep``'s files: ``sweep.csv`` (one row of 8 numbers per flat, speed and
    position), the NPZ (10 arrays of that shape, per wheel and realisation, 2 x quantities per
    sensor) and the percentile table."""
    runs = n_flats * n_speeds * n_positions
    per_run = 8 * CSV_BYTES + 8 * (10 * n_wheels + 2 * n_realisations
                                   + 2 * len(QUANTITIES) * n_sensors)
    return runs * per_run + n_flats * n_speeds * 8 * CSV_BYTES + FIGURES_BYTES


def check_simulate(case, flat, config, n_sensors: int, n_wheels: int, n_hanging: int) -> None:
    """Refuse a ``simulate`` case whose files would pass the output limit (one line naming
    the settings that make them large)."""
    speed = case["run.speed_kmh"] / 3.6
    steps = n_steps(flat, speed, config)
    check_output_size(simulate_bytes(steps, n_sensors, n_wheels, n_hanging),
                      f"{steps:,} time steps x {n_sensors:,} sensors (--sensors-m)",
                      bool(case.get("run.allow_large_output", False)))


def check_detector(case, n_speeds: int, n_sensors: int) -> None:
    """Refuse a ``detector`` case whose files (one flat's runs with ``n_sensors`` sensors
    and the detector's bays) would pass the output limit."""
    positions = int(case["run.impact_positions"])
    runs = n_speeds * positions
    size = sweep_bytes(1, n_speeds, positions, n_sensors=n_sensors) \
        + runs * (8 + int(case["detector.n_bays"])) * CSV_BYTES * (1 + 2 * n_sensors)
    check_output_size(size, f"{n_speeds:,} speeds (--speeds-kmh) x {positions} positions x "
                      f"{n_sensors:,} sensors (--sensors-m)",
                      bool(case.get("run.allow_large_output", False)))


def check_sweep(case, n_flats: int, n_speeds: int, n_wheels: int, n_realisations: int) -> None:
    """Refuse a ``sweep`` case whose files would pass the output limit."""
    positions = int(case["run.impact_positions"])
    check_output_size(sweep_bytes(n_flats, n_speeds, positions, n_wheels, n_realisations),
                      f"{n_flats} flat(s) x {n_speeds:,} speeds (--speeds-kmh) x {positions} "
                      f"positions x {n_realisations} realisations",
                      bool(case.get("run.allow_large_output", False)))

"""The entry point for one run: :func:`simulate`, a thin layer over the program core.

A run is a :class:`wfjax.scenario.description.Scenario` (checked once there) compiled into a
:class:`wfjax.program.core.Program` and run once, saving every step
(:class:`wfjax.program.core.Histories`); its windows and checks are
:mod:`wfjax.scenario.windows`. Contact models (``contact=``) come from
:mod:`wfjax.contact.registry`; rail roughness and rail-top inputs (``roughness=``) are read
as ``docs/real_track.md`` describes.
"""

from __future__ import annotations

import numpy as np

from .model import supports as supports_mod
from .params import Flat, Material, SimConfig, Track, Wheel
from .program.core import Run, compile_scenario
from .results import SimResult, one_wheel, summarise_run
from .scenario import sensors as sensor_mod
from .scenario.description import Scenario
from .scenario.windows import (
    RUN_IN_TIME,
    check_impact_position,
    check_speed,
    impact_position_from_angle,
    n_steps_for,
    simulation_window,
)

__all__ = ["simulate", "SimResult"]


def simulate(flat: Flat, speed: float, contact: str = "3d", impact_position: float = 0.0,
             wheel: Wheel | None = None, track: Track | None = None,
             material: Material | None = None, config: SimConfig | None = None,
             angle0: float | None = None, cache_dir=None,
             n_steps: int | None = None, sensors=None, detector=None,
             sensor_quantities=sensor_mod.QUANTITIES, vehicle=None, roughness=None,
             wheel_roughness=None) -> SimResult:
    """Simulate a wheel with ``flat`` rolling at ``speed`` over the discretely supported track.

    Args:
        flat: the wheel flat (:class:`wfjax.Flat`); ``Flat.none()`` for a smooth wheel.
        speed: train speed v [m/s] in (0, :data:`wfjax.params.MAX_SPEED`].
        contact: ``"3d"``, ``"2d"``, ``"hertz-trajectory"`` or ``"hertz-profile"``.
        impact_position: rail coordinate [m] in [0, L_S) measured from a sleeper centre where
            the flat centre meets the nominal contact point.
        wheel, track, material, config: model parameters (defaults: Tables 1 and 2, E = 210 GPa,
            nu = 0.3, :class:`SimConfig` defaults).
        angle0: alternatively the paper's initial angular position of the flat [rad] ahead of
            the contact at the start of the run; overrides ``impact_position`` (see module doc).
        cache_dir: where the track's modal model is cached (default: ``WFJAX_CACHE_DIR`` or
            ``~/.cache/wfjax``).
        n_steps: number of time steps (default: from ``config``); the time step becomes the
            window's duration / (n_steps - 1), as in :func:`wfjax.sweep`.
        sensors: [n_s] fixed rail positions [m] (x = 0 at the middle sleeper; within
            :func:`wfjax.scenario.sensors.allowed_range`): every quantity of
            :data:`wfjax.scenario.sensors.QUANTITIES` at each, as time histories.
        sensor_quantities: the subset of :data:`wfjax.scenario.sensors.QUANTITIES` to compute (each
            costs one modal dot product per sensor and step).
        detector: a :class:`wfjax.Detector`: its per-bay load estimate and peaks.
            The run's window is lengthened (``run_in``/``run_out``) so that the wheel
            crosses every instrumented bay.
        vehicle: a :class:`wfjax.model.vehicle.Vehicle` (default: the paper's single wheel): its
            wheels roll together on the track, ``flat`` on ``vehicle.flat_wheel`` (whose
            impact ``impact_position`` places), the others with the vehicle's flats or
            smooth; ``wheel`` is every wheel's model unless the vehicle gives its own.
        roughness: rail roughness, a :class:`wfjax.Roughness` (``values [n]``,
            rail coordinate x [m]; see :func:`loop_roughness` for how each model reads it).
        wheel_roughness: wheel roughness (periodic :class:`wfjax.Roughness`),
            read at the circumferential coordinate s [m] of each wheel.

    Returns:
        :class:`SimResult` with time histories [n_steps] and summary values (a vehicle's:
        the flat wheel's, plus every wheel's in the ``wheel_*`` fields).
    """
    scenario = Scenario.of(flat, contact, wheel=wheel, track=track, material=material,
                           config=config, vehicle=vehicle, roughness=roughness,
                           wheel_roughness=wheel_roughness, sensors=sensors,
                           sensor_quantities=sensor_quantities, detector=detector)
    v = check_speed(speed)
    run, x_imp, scenario = _run_of(scenario, v, impact_position, angle0, n_steps)
    program = compile_scenario(scenario, cache_dir)
    # summarised on the host: jnp would compile a dozen small programs for every step count
    hist = {k: np.asarray(a) for k, a in program.history(run).items()}
    fw = scenario.vehicle.flat_wheel
    quantities = () if program.data.sensors is None else program.data.sensors.quantities
    res = summarise_run(hist, fw, v, x_imp, run.dt, run.run_in, quantities,
                        np.asarray(program.data.struct.preload))
    if not scenario.per_wheel:
        res = one_wheel(res, fw)
    if program.data.struct.supports is not None:
        res = res._replace(support_force=hist["support_force"],
                           sleeper_disp=hist["sleeper_disp"],
                           hanging_sleepers=supports_mod.hanging_sleepers(scenario.track))
    if program.data.sensors is None:
        return res
    return res._replace(sensor_positions=np.asarray(program.data.sensors.positions))


def _run_of(scenario: Scenario, v: float, impact_position, angle0, n_steps) -> tuple:
    """(the :class:`Run` of :func:`simulate`, its impact position in the bay [m], the
    scenario on a track long enough for it, :meth:`Scenario.lengthened`): the window of the
    scenario's flat at speed ``v`` [m/s], checked on the track and the rail roughness;
    ``run.end`` is its step count."""
    config, spacing = scenario.config, float(scenario.track.sleeper_spacing)
    window = scenario.window_flat(scenario.flats[0])
    s_start, s_end = simulation_window(window, v, config)
    if angle0 is not None:
        radius = float(scenario.reference_wheel.radius)
        impact_position = float(impact_position_from_angle(angle0, s_start, radius, spacing))
    x_imp = check_impact_position(impact_position, scenario.track)
    n_auto, dt = n_steps_for(window, v, config)
    if n_steps is None:
        n_steps = n_auto
    elif int(n_steps) < 2:
        raise ValueError(f"n_steps must be >= 2, got {n_steps!r}")
    else:
        dt = (s_end - s_start) / v / (int(n_steps) - 1)
    scenario = scenario.lengthened([window], [v], [x_imp])
    scenario.check_settings(window, [v], [x_imp])
    x_abs = x_imp + scenario.shift
    run_in = int(0.5 * RUN_IN_TIME / dt)
    return Run(0, v, dt, x_abs + s_start, x_abs, run_in, int(n_steps), 0), x_imp, scenario

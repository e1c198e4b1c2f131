"""The entry point for one run: :func:`simulate` (and the pieces it shares with
:func:`wfjax.sweep` and the fits: the loop's roughness and a vehicle's contact laws).

The run itself is :func:`wfjax.loop.run.time_loop`; its windows and checks are
:mod:`wfjax.scenario.windows`. Contact models (``contact=``) come from
:mod:`wfjax.contact.registry`.

Roughness
---------
``simulate(roughness=, wheel_roughness=)`` and ``time_loop(roughness=)`` (a
:class:`wfjax.roughness.LoopRoughness`): point-contact laws add the contact-filtered
roughness to the approach, the 2D bedding and the direct 3D solve take it off the gap element
by element (:meth:`wfjax.contact.laws.ContactLaw.rough_nodes`); see ``docs/real_track.md``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from . import roughness as rough_mod
from . import sensors as sensor_mod
from . import supports as supports_mod
from . import vehicle as vehicle_mod
from ._xla import LOOP_COMPILER_OPTIONS
from .contact import registry
from .contact.laws import prepare
from .loop.observers import DetectorReadings, Sensors
from .loop.run import _LOOP_STATIC, time_loop
from .loop.structure import structure, vehicle_structure
from .params import Flat, Material, SimConfig, Track, Wheel
from .results import SimResult, summarise, summarise_vehicle
from .scenario.windows import (
    RUN_IN_TIME,
    check_impact_position,
    check_rail_span,
    check_speed,
    detector_config,
    impact_position_from_angle,
    n_steps_for,
    simulation_window,
    vehicle_window_flat,
    wheel_positions,
)

__all__ = ["simulate", "loop_roughness", "vehicle_laws", "SimResult"]


# simulate's own program: a top-level jit may carry compiler options, a nested one may not
_simulation = jax.jit(time_loop, static_argnames=_LOOP_STATIC,
                      compiler_options=LOOP_COMPILER_OPTIONS)


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
            :func:`wfjax.sensors.allowed_range`): every quantity of
            :data:`wfjax.sensors.QUANTITIES` at each, as time histories.
        sensor_quantities: the subset of :data:`wfjax.sensors.QUANTITIES` to compute (each
            costs one modal dot product per sensor and step).
        detector: a :class:`wfjax.sensors.Detector`: its per-bay load estimate and peaks.
            The run's window is lengthened (``run_in``/``run_out``) so that the wheel
            crosses every instrumented bay.
        vehicle: a :class:`wfjax.vehicle.Vehicle` (default: the paper's single wheel): its
            wheels roll together on the track, ``flat`` on ``vehicle.flat_wheel`` (whose
            impact ``impact_position`` places), the others with the vehicle's flats or
            smooth; ``wheel`` is every wheel's model unless the vehicle gives its own.
        roughness: rail roughness, a :class:`wfjax.roughness.Roughness` (``values [n]``,
            rail coordinate x [m]; see :func:`loop_roughness` for how each model reads it).
        wheel_roughness: wheel roughness (periodic :class:`wfjax.roughness.Roughness`),
            read at the circumferential coordinate s [m] of each wheel.

    Returns:
        :class:`SimResult` with time histories [n_steps] and summary values (a vehicle's:
        the flat wheel's, plus every wheel's in the ``wheel_*`` fields).
    """
    wheel = wheel or Wheel()
    track = track or Track()
    material = material or Material()
    config = config or SimConfig()
    v = check_speed(speed)
    wheels = [wheel] if vehicle is None else vehicle.wheel_list(wheel)
    flats = [flat] if vehicle is None else vehicle.flat_list(
        flat, lambda i: float(wheels[i].radius))
    if vehicle is not None:
        vehicle.check_spacing(wheels)
    for i, (f, w) in enumerate(zip(flats, wheels, strict=True)):
        if abs(float(f.wheel_radius) - float(w.radius)) > 1e-12:
            where = "" if vehicle is None else f" of wheel {i}"
            raise ValueError(
                f"flat.wheel_radius{where} ({float(f.wheel_radius)} m) must equal wheel.radius "
                f"({float(w.radius)} m)"
            )
    spacing = float(track.sleeper_spacing)
    if detector is not None:
        config = detector_config(detector, track, config, wheel_positions(vehicle, spacing))
    window_flat = flat
    if vehicle is not None:
        window_flat = vehicle_window_flat(vehicle, flats)
    s_start, s_end = simulation_window(window_flat, v, config)
    if angle0 is not None:
        impact_position = float(impact_position_from_angle(
            angle0, s_start, float(wheels[0 if vehicle is None else vehicle.flat_wheel].radius),
            spacing))
    x_imp = check_impact_position(impact_position, track)
    n_auto, dt = n_steps_for(window_flat, v, config)
    if n_steps is None:
        n_steps = n_auto
    elif int(n_steps) < 2:
        raise ValueError(f"n_steps must be >= 2, got {n_steps!r}")
    else:
        dt = (s_end - s_start) / v / (int(n_steps) - 1)
    registry.check(contact)
    run_in_steps = int(0.5 * RUN_IN_TIME / dt)
    if vehicle is None:
        struct = structure(wheel, track, config, cache_dir)
        law = prepare(contact, flat, wheel, track, material, config, cache_dir)
        x_abs = x_imp
    else:
        x_abs = x_imp + vehicle_mod.placement(vehicle, spacing)
        vehicle_mod.check_on_track(vehicle, track, x_abs + s_start, x_abs + s_end)
        struct = vehicle_structure(vehicle, wheels, track, config, cache_dir)
        law = vehicle_laws(contact, flats, wheels, track, material, config, cache_dir)
    sensor_spec = (None if sensors is None
                   else sensor_mod.sensor_spec(sensors, track, struct.track, sensor_quantities))
    det_spec = (None if detector is None
                else sensor_mod.detector_spec(detector, track, struct.track))
    rough = loop_roughness(roughness, wheel_roughness, wheels, track, material)
    offsets = np.zeros(1) if vehicle is None else vehicle.offsets()
    check_rail_span(roughness, x_abs + s_start + offsets.min(), x_abs + s_end + offsets.max())
    observers = tuple(o for o in (
        None if sensor_spec is None else Sensors(sensor_spec, run_in_steps),
        None if det_spec is None else DetectorReadings(det_spec)) if o is not None)
    hist = _simulation(law, struct, v, dt, x_abs + s_start, x_abs, int(n_steps),
                       config.newton_iterations, observers=observers,
                       precision=config.precision, roughness=rough)
    quantities = () if sensor_spec is None else sensor_spec.quantities
    if vehicle is None:
        res = summarise(hist, v, x_imp, dt, run_in_steps, quantities, struct.preload)
    else:
        res = summarise_vehicle(hist, vehicle.flat_wheel, v, x_imp, dt, run_in_steps,
                                quantities, struct.preload)
    if struct.supports is not None:
        res = res._replace(support_force=hist["support_force"],
                           sleeper_disp=hist["sleeper_disp"],
                           hanging_sleepers=supports_mod.hanging_sleepers(track))
    if sensor_spec is None:
        return res
    return res._replace(sensor_positions=np.asarray(sensor_spec.positions))


def loop_roughness(rail=None, wheel=None, wheels=None, track: Track | None = None,
                   material: Material | None = None):
    """The time loop's :class:`wfjax.roughness.LoopRoughness` (None when both are None).

    The contact filter's length (point-contact laws) is each wheel's static Hertz contact
    length (:func:`wfjax.roughness.static_contact_length` at its preload, on the Hertz radius
    sqrt(R_W R_R)), 13.1 mm for the default wheel and track: the patch the wheel rolls on between
    impacts, where roughness excites it.

    Args:
        rail: rail :class:`wfjax.roughness.Roughness` (``values [n]`` or, for
            :func:`wfjax.sweep`'s Monte Carlo, ``[R, n]``) or None.
        wheel: wheel roughness (periodic) or None. wheels: [n_wheels] :class:`Wheel`
            (default: one default wheel). track, material: as :func:`simulate`.
    """
    if rail is None and wheel is None:
        return None
    from .contact.laws import hertz_radius

    if rail is not None and rail.periodic:
        raise ValueError("roughness (rail) must not be periodic; a wheel profile goes to "
                         "wheel_roughness")
    if wheel is not None and not wheel.periodic:
        raise ValueError("wheel_roughness must be periodic (roughness.read_csv(..., "
                         "wheel_radius=R) or roughness.generate_wheel)")
    wheels = wheels or [Wheel()]
    track, material = track or Track(), material or Material()
    length = np.array([float(rough_mod.static_contact_length(
        float(w.preload), material, float(hertz_radius(w, track)))) for w in wheels])
    return rough_mod.LoopRoughness(rail, wheel, jnp.asarray(length))


def vehicle_laws(contact: str, flats: list[Flat], wheels: list[Wheel], track: Track,
                 material: Material, config: SimConfig, cache_dir=None) -> tuple:
    """[n] contact laws of the vehicle's wheels (one per distinct flat and wheel radius)."""
    laws, done = [], {}
    for f, w in zip(flats, wheels, strict=True):
        key = (id(f), float(w.radius)) if f.kind != "none" else ("none", float(w.radius))
        if key not in done:
            done[key] = prepare(contact, f, w, track, material, config, cache_dir)
        laws.append(done[key])
    return tuple(laws)

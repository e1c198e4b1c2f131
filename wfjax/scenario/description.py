"""What runs: :class:`Scenario`, one description of a run (or a family of runs), checked once.

A scenario holds the vehicle (one wheel is a vehicle of one: :meth:`Vehicle.single`), the
flats swept on its reference wheel, the track with its supports (or support realisations),
the rail and wheel roughness (with realisations), the instruments and the numerical
settings. It is a pytree: numbers (the flats' geometry, the roughness values, the parameter
classes' fields) are leaves; the contact model's name, the vehicle's layout, the instruments'
layout and the settings are static. Every check of these inputs is made here, in
:meth:`Scenario.of`; :mod:`wfjax.program` compiles a scenario into a program and runs it over a
grid of speeds x impact positions x flats x realisations.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import jax
import numpy as np

from ..contact import registry
from ..model import ends
from ..model.supports import hanging_sleepers
from ..model.vehicle import Vehicle, check_on_track, placement
from ..params import Flat, Material, SimConfig, Track, Wheel
from . import guards
from .roughness import Roughness
from .sensors import check_positions
from .windows import (
    check_impact_positions,
    check_rail_span,
    check_speeds,
    detector_config,
    impact_positions_grid,
    simulation_window,
    vehicle_window_flat,
    wheel_positions,
)

__all__ = ["Scenario", "rail_roughness"]


def rail_roughness(inputs) -> Roughness | None:
    """One rail :class:`Roughness` from ``inputs``: None, a Roughness, a rail-top input with
    ``add_to(roughness | None) -> Roughness`` (e.g. :class:`wfjax.Joint`), or a
    sequence of them (at most one Roughness; the others are added to it in turn)."""
    if inputs is None or isinstance(inputs, Roughness):
        return inputs
    items = [inputs] if hasattr(inputs, "add_to") else list(inputs)
    bases = [r for r in items if isinstance(r, Roughness)]
    if len(bases) > 1:
        raise ValueError("roughness: give at most one rail Roughness (add joints and other "
                         "rail-top inputs to it)")
    rough = bases[0] if bases else None
    for item in items:
        if isinstance(item, Roughness):
            continue
        if not hasattr(item, "add_to"):
            raise ValueError(f"roughness: expected a wfjax.Roughness or a rail-top input with "
                             f"add_to (e.g. wfjax.Joint), got {type(item).__name__}")
        rough = item.add_to(rough)
    return rough


@dataclasses.dataclass(frozen=True)
class Scenario:
    """A checked description of what runs (build with :meth:`of`).

    Attributes:
        flats: [n_flats] :class:`Flat` swept on ``vehicle.flat_wheel`` (traced geometry in a
            fit).
        contact: contact model name (:func:`wfjax.contact.registry.names`), static.
        vehicle: :class:`Vehicle`, static; one wheel is ``Vehicle.single()``.
        wheels: [n_wheels] :class:`Wheel`, the vehicle's wheel models.
        track: :class:`Track` (the first of ``tracks`` when those are given).
        material: :class:`Material`. config: :class:`SimConfig` (static; a detector's
            run-in/run-out already lengthened).
        roughness: rail :class:`Roughness` (values [n] or [R, n]) or None.
        wheel_roughness: periodic wheel :class:`Roughness` or None.
        tracks: [R] support realisations (:class:`Track`) or None.
        sensors: [n_s] sensor positions [m] or None; sensor_quantities: their quantities.
        detector: :class:`wfjax.Detector` or None (static).
        per_wheel: whether results report every wheel (a vehicle was given), static.
    """

    flats: tuple
    contact: str
    vehicle: Vehicle
    wheels: tuple
    track: Track
    material: Material
    config: SimConfig
    roughness: Any = None
    wheel_roughness: Any = None
    tracks: tuple | None = None
    sensors: Any = None
    sensor_quantities: tuple = ()
    detector: Any = None
    per_wheel: bool = False

    @classmethod
    def of(cls, flats: Flat | Sequence[Flat], contact: str = "3d", *,
           wheel: Wheel | None = None, track: Track | None = None,
           material: Material | None = None, config: SimConfig | None = None,
           vehicle: Vehicle | None = None, roughness=None, wheel_roughness=None,
           tracks=None, sensors=None, sensor_quantities=(), detector=None) -> Scenario:
        """A scenario from the entry points' arguments (defaults: the paper's Tables 1-2,
        E = 210 GPa, nu = 0.3, :class:`SimConfig` defaults, one wheel), checked.

        ``roughness`` may also be a rail-top input such as :class:`wfjax.Joint`, or a
        sequence of them and one Roughness (:func:`rail_roughness`). Raises a one-line
        ``ValueError`` naming the argument for anything inconsistent.
        """
        registry.check(contact)
        wheel, track = wheel or Wheel(), track or Track()
        material = material or Material()
        config = (config or SimConfig()).resolved(reading=detector is not None)
        flat_list = (flats,) if isinstance(flats, Flat) else tuple(flats)
        if not flat_list:
            raise ValueError("flats must contain at least one Flat")
        per_wheel = vehicle is not None
        vehicle = vehicle or Vehicle.single()
        wheels = tuple(vehicle.wheel_list(wheel))
        vehicle.check_spacing(list(wheels))
        ref = wheels[vehicle.flat_wheel]
        for f in flat_list:
            if abs(float(np.asarray(f.wheel_radius)) - float(ref.radius)) > 1e-12:
                where = f" of wheel {vehicle.flat_wheel}" if per_wheel else ""
                raise ValueError(f"flat.wheel_radius ({float(np.asarray(f.wheel_radius))} m) "
                                 f"must equal the radius{where} ({float(ref.radius)} m)")
        if tracks is not None:
            tracks = tuple(ends.resolved(t) for t in _check_tracks(tracks, per_wheel, sensors,
                                                                    detector))
            track = tracks[0]
        track = guards.holding_instruments(ends.resolved(track), sensors, detector)
        if sensors is not None:
            check_positions(sensors, track)
        rough = rail_roughness(roughness)
        _check_roughness(rough, wheel_roughness, tracks)
        if detector is not None:
            config = detector_config(detector, track, config,
                                     wheel_positions(vehicle, float(track.sleeper_spacing)))
        return cls(flat_list, contact, vehicle, wheels, track, material, config, rough,
                   wheel_roughness, tracks, sensors, tuple(sensor_quantities), detector,
                   per_wheel)

    @property
    def reference_wheel(self) -> Wheel:
        """The wheel that carries the swept flats (``vehicle.flat_wheel``)."""
        return self.wheels[self.vehicle.flat_wheel]

    @property
    def n_realisations(self) -> int:
        """R: roughness or support realisations (1 without)."""
        counts = _realisation_counts(self.roughness, self.wheel_roughness)
        if self.tracks is not None:
            counts.add(len(self.tracks))
        return counts.pop() if counts else 1

    @property
    def shift(self) -> float:
        """Rail coordinate [m] of the reference wheel's impact bay (the vehicle's placement)."""
        return placement(self.vehicle, float(self.track.sleeper_spacing))

    def vehicle_flats(self, swept: Flat) -> list[Flat]:
        """[n_wheels] flats: ``swept`` on the reference wheel, the vehicle's elsewhere."""
        return self.vehicle.flat_list(swept, lambda i: float(self.wheels[i].radius))

    def window_flat(self, swept: Flat) -> Flat:
        """The flat whose windows cover every wheel's flat when ``swept`` is the swept one."""
        return vehicle_window_flat(self.vehicle, self.vehicle_flats(swept))

    def speeds(self, speeds) -> np.ndarray:
        """[n] checked train speeds [m/s]."""
        return check_speeds(speeds)

    def positions(self, impact_positions) -> np.ndarray:
        """[n] checked impact positions [m]: a count evenly covering one bay, or positions
        (:func:`wfjax.scenario.windows.check_impact_positions`)."""
        if np.ndim(impact_positions) == 0:
            return impact_positions_grid(impact_positions, float(self.track.sleeper_spacing))
        return check_impact_positions(impact_positions, self.track)

    def path(self, window: Flat, speeds, positions) -> tuple[float, float]:
        """(lo, hi) [m]: the rail span that the reference wheel travels over in the runs of
        ``window``'s flat at ``speeds`` [m/s] and ``positions`` [m]."""
        s = [simulation_window(window, float(v), self.config) for v in (min(speeds),
                                                                         max(speeds))]
        s0, s1 = min(a for a, _ in s), max(b for _, b in s)
        return (float(np.min(positions)) + self.shift + s0,
                float(np.max(positions)) + self.shift + s1)

    def lengthened(self, windows: Sequence[Flat], speeds, positions) -> Scenario:
        """This scenario on a track long enough for the runs of every flat of ``windows``
        at ``speeds`` [m/s] and ``positions`` [m]: a track whose supports are scalars is
        lengthened to the least even ``n_bays`` that keeps every wheel's path
        :func:`~wfjax.scenario.guards.end_margin` from the clamped ends (``Track.n_bays`` is
        the least length); a track with per-sleeper supports or realisations as given (the
        guards refuse it if it is too short)."""
        if not guards.extendable(self.track) or self.tracks is not None:
            return self
        offsets = self.vehicle.offsets()
        paths = [self.path(w, speeds, positions) for w in windows]
        lo = min(p[0] for p in paths) + offsets.min()
        hi = max(p[1] for p in paths) + offsets.max()
        # a vehicle's runs also hold its wheels a bay past the path (check_settings)
        on_rail = hi + float(self.track.sleeper_spacing) if self.per_wheel else hi
        track = guards.at_least(self.track, max(max(hi, -lo) + guards.end_margin(self.track),
                                                on_rail))
        return self if track is self.track else dataclasses.replace(self, track=track)

    def run_settings(self, n_modes: int) -> dict:
        """The numerical settings the runs use, as a JSON-ready dict with units in the names:
        ``config``'s resolved mode cut-off, step caps and precision setting, the track's
        bays as lengthened and its elements per bay, and ``n_modes``, the track model's
        complex modes."""
        c, tr = self.config, self.track
        return {"track_max_frequency_Hz": float(c.track_max_frequency),
                "max_time_step_s": float(c.max_time_step),
                "max_travel_step_m": float(c.max_travel_step), "precision": c.precision,
                "n_bays": int(tr.n_bays), "elements_per_bay": int(tr.elements_per_bay),
                "n_modes": int(n_modes)}

    def check_settings(self, window: Flat, speeds, positions) -> None:
        """Refuse, in one line, the runs of ``window``'s flat at ``speeds`` [m/s] and
        ``positions`` [m] unless every wheel stays on the track and on the rail roughness
        and every numerical setting passes the physics guards (:mod:`.guards`; with
        ``config.allow_inaccurate`` their findings warn instead)."""
        offsets = self.vehicle.offsets()
        lo, hi = self.path(window, speeds, positions)
        if self.per_wheel:
            check_on_track(self.vehicle, self.track, lo, hi + float(self.track.sleeper_spacing))
        check_rail_span(self.roughness, lo + offsets.min(), hi + offsets.max())
        guards.enforce(self.guard_findings(speeds, (lo + offsets.min(), hi + offsets.max())),
                       self.config)

    def guard_findings(self, speeds, path: tuple[float, float]) -> list[str]:
        """The physics guards' findings (one line each) for runs at ``speeds`` [m/s] whose
        wheels travel over ``path`` (lo, hi) [m]: every wheel's scales, the track, the
        contact element, the path's distance to the clamped ends (the sensors' is checked
        with them, :func:`wfjax.scenario.sensors.check_positions`)."""
        out = []
        for sc in dict.fromkeys(guards.scales(w, self.track, self.material)
                                for w in self.wheels):  # a vehicle's like wheels: once
            out += guards.step_findings(self.config, speeds, sc)
            out += guards.track_findings(self.track, self.config, sc)
            out += guards.element_findings(self.contact, self.config, sc)
        out += guards.end_findings(self.track, *path)
        return list(dict.fromkeys(out))


def _check_tracks(tracks, per_wheel: bool, sensors, detector) -> tuple:
    tracks = tuple(tracks)
    if not tracks or per_wheel or sensors is not None or detector is not None:
        raise ValueError("tracks (support realisations) must be a non-empty sequence of "
                         "Track, and cannot be combined with a vehicle, sensors or a "
                         "detector")
    if any(hanging_sleepers(tr).size for tr in tracks):
        raise ValueError("tracks (support realisations) must not have hanging sleepers "
                         "(ballast_gap > 0): sweep one such track at a time")
    return tracks


def _realisation_counts(rail, wheel) -> set:
    """The realisation counts R of the roughness profiles with values [R, n]."""
    return {int(np.shape(r.values)[0]) for r in (rail, wheel)
            if r is not None and np.ndim(r.values) == 2}


def _check_roughness(rail, wheel, tracks) -> None:
    if rail is not None and rail.periodic:
        raise ValueError("roughness (rail) must not be periodic; a wheel profile goes to "
                         "wheel_roughness")
    if wheel is not None and not wheel.periodic:
        raise ValueError("wheel_roughness must be periodic (roughness.read_csv(..., "
                         "wheel_radius=R) or roughness.generate_wheel)")
    counts = _realisation_counts(rail, wheel)
    if len(counts) > 1:
        raise ValueError(f"roughness and wheel_roughness must hold the same number of "
                         f"realisations, got {sorted(counts)}")
    if tracks is not None and counts and counts != {len(tracks)}:
        raise ValueError(f"roughness realisations ({counts.pop()}) and support realisations "
                         f"(tracks: {len(tracks)}) must be as many when both are given")


jax.tree_util.register_dataclass(
    Scenario,
    data_fields=["flats", "wheels", "track", "material", "roughness", "wheel_roughness",
                 "tracks", "sensors"],
    meta_fields=["contact", "vehicle", "config", "sensor_quantities", "detector",
                 "per_wheel"])

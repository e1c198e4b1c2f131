"""Differentiable force models of a fit: a flat's geometry -> forces [N], over the program core.

Each model is a :class:`wfjax.scenario.description.Scenario` (any vehicle, rail and wheel
roughness, a track with varying supports, a detector) compiled once into a
:class:`wfjax.program.core.Program`; an evaluation traces the swept flat's contact law
(:class:`TracedLaw`) and runs a rectangular batch of runs (every run the step count of the
slowest, :func:`wfjax.scenario.windows.batch_windows`) through
:meth:`~wfjax.program.core.Program.forward`, differentiated as its differentiation object says
(:class:`~wfjax.program.core.Autodiff`, :class:`~wfjax.program.core.Checkpointed`,
:class:`~wfjax.program.core.Adjoint`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._xla import to_device
from ..contact.laws import prepare, prepare_family_range
from ..contact.protocol import ContactLaw
from ..contact.table_law import TableLaw
from ..params import Flat, Material, SimConfig, Track, Wheel, new_flat_length
from ..program.core import Adjoint, Autodiff, Checkpointed, Histories, Run, compile_scenario
from ..scenario.description import Scenario
from ..scenario.windows import batch_windows, check_impact_position

__all__ = ["smooth_max", "fit_range", "TracedLaw", "ForceModel", "max_force_model",
           "detector_model", "history_model", "FIT_DEPTH_FACTOR", "FIT_LENGTH_FACTOR",
           "MAX_FAMILY_ROUNDS"]


def smooth_max(x, temperature=None, axis=-1):
    """T log sum exp(x / T) along ``axis`` (same units as x, e.g. N); hard max if T is 0/None.

    Lies in [max x, max x + T log n] for n candidates; differentiable everywhere.
    """
    if not temperature:
        return jnp.max(x, axis=axis)
    return temperature * jax.nn.logsumexp(jnp.asarray(x) / temperature, axis=axis)


FIT_DEPTH_FACTOR = 1.4  # the 3D family of a fit covers depths in [d0 / 1.4, 1.4 d0]
FIT_LENGTH_FACTOR = 1.2  # ... and l / l0 within a factor 1.2 of the start (rounded flats)
MAX_FAMILY_ROUNDS = 5  # restarts of a 3D fit on a family around where it left the last one


def fit_range(reference: Flat, wheel_radius: float, depth_factor: float = FIT_DEPTH_FACTOR,
              length_factor: float = FIT_LENGTH_FACTOR):
    """(depths [m], length factors l / l0 or None) spanning the range a 3D fit may visit.

    Depths from d0 / ``depth_factor`` to d0 x ``depth_factor`` (within the model's 0-5 mm);
    rounded flats from l / l0 = lambda0 / ``length_factor`` (at least pi/2, the shortest
    rounded flat) to lambda0 x ``length_factor``. The parametric family of the fit covers this
    range; :func:`wfjax.fit.fit_flat` warns when the fitted flat ends on its edge.
    """
    from ..params import MAX_FLAT_DEPTH

    d0 = float(reference.depth)
    depths = [d0 / depth_factor, min(d0 * depth_factor, MAX_FLAT_DEPTH)]
    if reference.kind == "new":
        return depths, None
    factor = float(reference.length) / float(new_flat_length(d0, wheel_radius))
    return depths, [max(factor / length_factor, math.pi / 2), factor * length_factor]


@dataclasses.dataclass(frozen=True)
class TracedLaw:
    """The swept flat's contact law with its geometry traced: ``law(flat)``.

    ``family``: the 3D parametric family over :func:`fit_range` (``"3d"``, new or rounded
    flats); ``table_spec``: the exact table's layout (``"3d"``, a measured profile, rebuilt
    at every evaluation); otherwise the model's own traced law.
    """

    contact: str
    wheel: Wheel
    track: Track
    material: Material
    config: SimConfig
    table_spec: Any = None
    family: Any = None

    @classmethod
    def of(cls, scenario: Scenario, reference: Flat, cache_dir=None) -> TracedLaw:
        """The traced law of ``scenario``'s reference wheel, sized by ``reference``."""
        sc = scenario
        wheel = sc.reference_wheel
        spec3d = family = None
        if sc.contact == "3d" and reference.kind == "profile":
            from ..contact.table_spec import table_spec

            spec3d = table_spec(reference, float(wheel.radius), float(sc.track.rail_head_radius),
                                sc.material, element_size=sc.config.contact_element)
        elif sc.contact == "3d":
            depths, factors = fit_range(reference, float(wheel.radius))
            family = prepare_family_range(reference.kind, depths, factors, wheel, sc.track,
                                          sc.material, sc.config, cache_dir)
        return cls(sc.contact, wheel, sc.track, sc.material, sc.config, spec3d, family)

    def __call__(self, flat: Flat) -> ContactLaw:
        if self.table_spec is not None:  # a measured profile: its exact table, built traced
            from ..contact import tables

            return TableLaw(tables.build_table_3d(
                flat, float(self.wheel.radius), float(self.track.rail_head_radius),
                self.material, element_size=self.config.contact_element, spec=self.table_spec))
        return prepare(self.contact, flat, self.wheel, self.track, self.material, self.config,
                       family=self.family)


class ForceModel(NamedTuple):
    """A differentiable map flat -> forces [N], with the program and traced law behind it.

    ``model(flat)`` returns [n_out] forces; depth, length and profile values of ``flat`` may be
    traced (``jax.grad``/``jacfwd``), its kind and ``extent_bound`` are fixed.
    """

    fn: Any
    program: Any
    law: TracedLaw
    info: dict

    def __call__(self, flat: Flat):
        return self.fn(flat)


def _differentiation(checkpoint: bool, adjoint: bool):
    if adjoint:
        return Adjoint()
    return Checkpointed() if checkpoint else Autodiff()


def _fit_program(reference: Flat, extent_bound, model: dict, cache_dir, detector=None, *,
                 grid):
    """(program, traced law, window flat) of a fit's model (``model``: the scenario's
    keyword arguments: contact, wheel, track, material, config, vehicle, roughness,
    wheel_roughness); ``grid`` (speeds [m/s], impact positions): checked by the physics
    guards before the program is compiled."""
    ref = dataclasses.replace(reference, extent_bound=reference.half_extent
                              if extent_bound is None else float(extent_bound))
    contact = model.pop("contact")
    scenario = Scenario.of(ref, contact, detector=detector, **model)
    if scenario.n_realisations != 1:
        raise ValueError("a fit runs on one roughness realisation: give roughness values [n], "
                         f"not {scenario.n_realisations} realisations")
    speeds, positions = scenario.speeds(grid[0]), np.atleast_1d(scenario.positions(grid[1]))
    scenario = scenario.lengthened([scenario.window_flat(ref)], speeds, positions)
    scenario.check_settings(scenario.window_flat(ref), speeds, positions)
    program = compile_scenario(scenario, cache_dir)
    return program, TracedLaw.of(scenario, ref, cache_dir), scenario.window_flat(ref)


def _batch(program, window: Flat, speeds, positions) -> tuple[Run, np.ndarray, np.ndarray]:
    """(the [B] runs of speeds x positions, rectangular: every one the step count of the
    slowest, their run-in steps [B], their start s_0 [B] m relative to the impact); sets
    ``program.n_steps``."""
    sc = program.scenario
    v = sc.speeds(speeds)  # checked by the guards in _fit_program, before compiling
    n_steps, dt, s0, run_in = batch_windows(window, v, sc.config)
    vv, pp = (a.ravel() for a in np.meshgrid(v, positions, indexing="ij"))
    dd, ss, rr = (np.repeat(a, np.size(positions)) for a in (dt, s0, run_in))
    program.n_steps = int(n_steps)
    zeros = np.zeros(vv.size, int)
    x_imp = pp + sc.shift
    runs = Run(zeros, vv, dd, x_imp + ss, x_imp, rr, np.full(vv.size, n_steps), zeros)
    return jax.tree.map(lambda a: to_device(np.asarray(a)), runs), rr, ss


def max_force_model(speeds, reference: Flat, contact: str = "hertz-trajectory",
                    impact_positions=3, temperature: float | None = 1e3,
                    time_temperature: float | None = None, extent_bound: float | None = None,
                    wheel: Wheel | None = None, track: Track | None = None,
                    material: Material | None = None, config: SimConfig | None = None,
                    checkpoint: bool = False, cache_dir=None, adjoint: bool = False,
                    vehicle=None, roughness=None, wheel_roughness=None) -> ForceModel:
    """Differentiable maximum impact force [N] at each of ``speeds`` (impact load detector).

    For every speed and impact position one simulation is run (all with the step count of the
    slowest, each with its own time step: one rectangular batch,
    :func:`wfjax.scenario.windows.batch_windows`, finer than :func:`wfjax.simulate`'s time step
    at most speeds); its maximum force after the run-in (``smooth_max`` with
    ``time_temperature``, hard by default) is then reduced over the positions with
    ``smooth_max(temperature)`` [N].

    Args:
        speeds: [n] train speeds [m/s].
        reference: a concrete flat of the kind to be evaluated (sizes windows and 3D tables).
        contact: one of :func:`wfjax.contact.registry.names`.
        impact_positions: number of positions evenly covering a bay, or [m] positions [m].
        temperature, time_temperature: smooth-maximum temperatures [N] (None: hard max).
        extent_bound: static bound [m] of the flat's half extent (default: the reference's).
        wheel, track, material, config: model parameters (default track:
            ``Track()``, as :func:`wfjax.simulate` and :func:`wfjax.sweep`); ``track`` may
            have varying supports.
        checkpoint: run the simulations sequentially under ``jax.checkpoint`` (reverse-mode
            memory: one time history at a time).
        adjoint: reverse mode through the hand-written adjoint of the time loop
            (:mod:`wfjax.loop.adjoint`: the same forces; measured for 10 speeds of the 3D family,
            value_and_grad at 1.3-1.4 forward evaluations instead of 3.3-4); the model then
            supports reverse mode only (``grad``/``jacrev``, not ``jacfwd``). Default False:
            plain autodiff.
        vehicle: a :class:`wfjax.model.vehicle.Vehicle` (the flat on ``vehicle.flat_wheel``, whose
            force is returned), as :func:`wfjax.simulate`. roughness, wheel_roughness: rail
            (or rail-top inputs) and wheel roughness of one realisation, as
            :func:`wfjax.simulate`.

    Returns:
        :class:`ForceModel`: ``model(flat) -> [n]`` forces [N].
    """
    program, law, window = _fit_program(reference, extent_bound, dict(
        contact=contact, wheel=wheel, track=track, material=material, config=config,
        vehicle=vehicle, roughness=roughness, wheel_roughness=wheel_roughness), cache_dir,
        grid=(speeds, impact_positions))
    v, pos = program.scenario.speeds(speeds), program.scenario.positions(impact_positions)
    runs, run_in, _ = _batch(program, window, v, pos)
    after = to_device(np.arange(program.n_steps)[None, :] >= run_in[:, None])
    fw, how = program.scenario.vehicle.flat_wheel, _differentiation(checkpoint, adjoint)

    def fn(flat: Flat):
        force = program.forward(law(flat), runs, Histories(), how)["force"][..., fw]
        peak = smooth_max(jnp.where(after, force, 0.0), time_temperature, axis=-1)
        return smooth_max(peak.reshape(v.size, pos.size), temperature, axis=-1)

    info = {"kind": "max_force", "speeds": v, "impact_positions": pos,
            "n_steps": program.n_steps, "time_steps": np.asarray(runs.dt[::pos.size]),
            "temperature": temperature, "time_temperature": time_temperature,
            "adjoint": adjoint}
    return ForceModel(fn, program, law, info)


def detector_model(speeds, reference: Flat, detector=None, per_bay: bool = False,
                   contact: str = "hertz-trajectory", impact_positions=3,
                   temperature: float | None = 1e3, extent_bound: float | None = None,
                   wheel: Wheel | None = None, track: Track | None = None,
                   material: Material | None = None, config: SimConfig | None = None,
                   cache_dir=None, adjoint: bool = False, vehicle=None, roughness=None,
                   wheel_roughness=None) -> ForceModel:
    """Differentiable detector readings [N] of the flat's wheel at each of ``speeds`` [m/s].

    Every run carries the detector (:class:`wfjax.Detector`, default 3 bays) in its
    scan; windows are lengthened so that every wheel crosses every bay. ``per_bay``: the
    readings of every bay at the one position ``impact_positions`` (a single [m] value),
    flattened [n * n_bays]; otherwise the maximum over bays, then ``smooth_max(temperature)``
    [N] over the impact positions (count or [m] array), [n]. ``adjoint``: reverse mode
    through :mod:`wfjax.loop.adjoint` (as :func:`max_force_model`: the same readings, reverse mode
    only). vehicle, roughness, wheel_roughness: as :func:`max_force_model`.
    """
    from ..scenario import sensors as sensor_mod

    detector = detector or sensor_mod.Detector()
    program, law, window = _fit_program(reference, extent_bound, dict(
        contact=contact, wheel=wheel, track=track, material=material, config=config,
        vehicle=vehicle, roughness=roughness, wheel_roughness=wheel_roughness), cache_dir,
        detector, grid=(speeds, impact_positions))
    v = program.scenario.speeds(speeds)
    pos = np.atleast_1d(program.scenario.positions(impact_positions))
    if per_bay and pos.size != 1:
        raise ValueError(f"per-bay detector data needs one impact position, got {pos!r}")
    runs, _, _ = _batch(program, window, v, pos)
    fw, how = program.scenario.vehicle.flat_wheel, _differentiation(False, adjoint)

    def fn(flat: Flat):
        out = program.forward(law(flat), runs, Histories(instruments=False), how)
        peaks = out["detector_peak"][:, fw]  # [n * n_pos, n_bays]
        if per_bay:
            return peaks.reshape(-1)
        return smooth_max(jnp.max(peaks, axis=-1).reshape(v.size, pos.size), temperature,
                          axis=-1)

    info = {"kind": "detector", "speeds": v, "impact_positions": pos,
            "n_steps": program.n_steps, "time_steps": np.asarray(runs.dt[::pos.size]),
            "temperature": temperature, "detector": detector, "per_bay": per_bay,
            "adjoint": adjoint}
    return ForceModel(fn, program, law, info)


def history_model(t, speed: float, reference: Flat, contact: str = "hertz-trajectory",
                  impact_position: float = 0.0, extent_bound: float | None = None,
                  wheel: Wheel | None = None, track: Track | None = None,
                  material: Material | None = None, config: SimConfig | None = None,
                  cache_dir=None, adjoint: bool = False, vehicle=None, roughness=None,
                  wheel_roughness=None) -> ForceModel:
    """Differentiable contact force [N] of the flat's wheel at times ``t`` [s] (t = 0: flat
    centre at the contact).

    The simulation of :func:`wfjax.simulate` at ``speed`` [m/s] and ``impact_position`` [m],
    linearly interpolated at ``t``, which must lie inside the simulated window.
    ``adjoint``: reverse mode through :mod:`wfjax.loop.adjoint` (as :func:`max_force_model`).
    vehicle, roughness, wheel_roughness: as :func:`max_force_model`.
    """
    program, law, window = _fit_program(reference, extent_bound, dict(
        contact=contact, wheel=wheel, track=track, material=material, config=config,
        vehicle=vehicle, roughness=roughness, wheel_roughness=wheel_roughness), cache_dir,
        grid=([speed], [impact_position]))
    pos = check_impact_position(impact_position, program.scenario.track)
    runs, _, s0 = _batch(program, window, [speed], [pos])
    dt, s0 = float(runs.dt[0]), float(s0[0])
    t = np.asarray(t, dtype=float)
    t_first, t_last = s0 / speed, s0 / speed + dt * (program.n_steps - 1)
    if t.min() < t_first or t.max() > t_last:
        raise ValueError(f"t must lie in the simulated window [{t_first * 1e3:.1f}, "
                         f"{t_last * 1e3:.1f}] ms (t = 0: flat centre at the contact), got "
                         f"[{t.min() * 1e3:.1f}, {t.max() * 1e3:.1f}] ms")
    t_sim = jnp.asarray(t_first + dt * np.arange(program.n_steps))
    fw, how = program.scenario.vehicle.flat_wheel, _differentiation(False, adjoint)

    def fn(flat: Flat):
        force = program.forward(law(flat), runs, Histories(), how)["force"][0, :, fw]
        return jnp.interp(jnp.asarray(t), t_sim, force)

    info = {"kind": "history", "speed": float(speed), "impact_position": pos,
            "n_steps": program.n_steps, "time_step": dt, "t_sim": np.asarray(t_sim),
            "adjoint": adjoint}
    return ForceModel(fn, program, law, info)

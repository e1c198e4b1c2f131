"""What a run saves besides the contact histories: composable observers of the time loop.

An observer is a small pytree (numbers and specs are leaves; what changes the program, such
as whether histories are kept, is static) with three methods, as ``optax`` composes
``(init, update)`` transforms:

* ``init(ctx) -> state``: its running state (e.g. extremes) before the first reading;
* ``update(state, reading, ctx) -> (state, {name: value})``: one instant of the run
  (:class:`Reading`: the modal state after the step, the forces, the wheels' positions, ...);
  the dict holds the per-step values kept as histories (``[n_steps, ...]`` in the result);
* ``finalize(state, ctx) -> {name: value}``: its summaries.

Instruments (:class:`Sensors`, :class:`DetectorReadings`) split ``update`` into
``readout(reading, ctx) -> value``, linear in the modal state and the forces at fixed wheel
positions, and ``reduce(state, value, reading, ctx) -> (state, {name: value})``, which may read the
reading's step index and positions but not its modal state or forces: :mod:`wfjax.loop.adjoint`
transposes the readout at each step and differentiates the reduction over the recorded
values.

The time loop (:func:`wfjax.loop.run.time_loop`) feeds every observer the static start
(step 0) and every step, in its scan; the step itself knows no instrument. A new output is one
observer class here (or in the user's code) and its use by an entry point. Every running
extreme is reduced the same way, by :func:`running_max` / :func:`running_min` over the counted
steps.

Steps counted in summaries: ``run_in <= n < end`` (``end``: the run's own window when a batch
runs shorter windows for its longest one's step count; None: every step).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax.numpy as jnp

from ..fields import pytree
from ..scenario import sensors as sensor_mod

__all__ = ["Reading", "LoopContext", "Sensors", "DetectorReadings", "HangingSleepers",
           "OwnCompliance", "running_max", "running_min", "counted"]


class Reading(NamedTuple):
    """One instant of a run, as every observer sees it.

    Shapes: n = wheels, M = track modes, n_s = hanging sleepers. ``n``: step index (0 = the
    static start); ``q`` [M] complex: the track's modal state after the step; ``force`` [n]
    N; ``x`` [n] m: the wheels' rail positions; ``own_compliance`` [n] m/N: each wheel's rail
    compliance within the step from the kept modes; ``support``: () or, with hanging
    sleepers, (force [n_s] N upwards on each sleeper, closure [n_s] m).
    """

    n: Any
    q: Any
    force: Any
    x: Any
    own_compliance: Any
    support: tuple


class LoopContext(NamedTuple):
    """What observers may read of the run: ``model`` (the track's modal model, in the loop's
    precision), ``n_wheels``, ``real`` (the loop's float dtype) and ``supports`` (the hanging
    sleepers' :class:`wfjax.model.supports.OneSidedSupports`, or None)."""

    model: Any
    n_wheels: int
    real: Any
    supports: Any


def counted(n, start=0, end=None):
    """Whether step ``n`` counts in a summary: ``start <= n`` and ``n < end`` (traced ints)."""
    late = n >= start
    return late if end is None else late & (n < end)


def running_max(acc, value, on):
    """``max(acc, value)`` where ``on``, else ``acc`` (elementwise)."""
    return jnp.where(on, jnp.maximum(acc, value), acc)


def running_min(acc, value, on):
    """``min(acc, value)`` where ``on``, else ``acc`` (elementwise)."""
    return jnp.where(on, jnp.minimum(acc, value), acc)


def _supports(r: Reading):
    """The hanging sleepers' support forces [n_s] N at ``r``, or None without them."""
    return r.support[0] if r.support else None


@pytree(static=("history",))
class Sensors:
    """Readings at fixed rail positions (:class:`wfjax.scenario.sensors.SensorSpec`): their max and
    min over the counted steps (``sensor_max``, ``sensor_min`` [n_quantities, n_s]) and, with
    ``history``, the time histories (``sensors`` [n_steps, n_quantities, n_s])."""

    spec: Any
    run_in: Any = 0
    end: Any = None
    history: bool = True

    def init(self, ctx: LoopContext):
        shape = (len(self.spec.quantities), self.spec.positions.shape[0])
        return jnp.full(shape, -jnp.inf, ctx.real), jnp.full(shape, jnp.inf, ctx.real)

    def readout(self, r: Reading, ctx: LoopContext):
        """The readings [n_quantities, n_s] at ``r``: linear in (``r.q``, ``r.force``) at
        fixed ``r.x``."""
        return sensor_mod.evaluate(self.spec, ctx.model, r.q, r.force, r.x, _supports(r))

    def reduce(self, state, y, r: Reading, ctx: LoopContext):
        """The running extremes after readings ``y`` at ``r`` (its step index only)."""
        on = counted(r.n, self.run_in, self.end)
        state = running_max(state[0], y, on), running_min(state[1], y, on)
        return state, ({"sensors": y} if self.history else {})

    def update(self, state, r: Reading, ctx: LoopContext):
        return self.reduce(state, self.readout(r, ctx), r, ctx)

    def finalize(self, state, ctx: LoopContext):
        return {"sensor_max": state[0], "sensor_min": state[1]}


@pytree(static=("history",))
class DetectorReadings:
    """A wheel impact load detector (:class:`wfjax.scenario.sensors.DetectorSpec`): every wheel's
    peak estimate per bay while it is between the bay's bridges (``detector_peak``
    [n_wheels, n_bays] N) and, with ``history``, the ungated estimate (``detector_load``
    [n_steps, n_bays] N)."""

    spec: Any
    end: Any = None
    history: bool = True

    def init(self, ctx: LoopContext):
        return jnp.full((ctx.n_wheels,) + self.spec.left.shape, -jnp.inf, ctx.real)

    def readout(self, r: Reading, ctx: LoopContext):
        """The ungated estimate [n_bays] N at ``r``: linear in (``r.q``, ``r.force``) at
        fixed ``r.x``."""
        return sensor_mod.detector_load(self.spec, ctx.model, r.q, r.force, r.x,
                                        _supports(r))[0]

    def reduce(self, state, est, r: Reading, ctx: LoopContext):
        """The running peaks after estimate ``est`` at ``r`` (its step index and the wheels'
        positions, which gate the bays)."""
        gate = sensor_mod.detector_gate(self.spec, r.x)
        state = running_max(state, est, gate & counted(r.n, 0, self.end))
        return state, ({"detector_load": est} if self.history else {})

    def update(self, state, r: Reading, ctx: LoopContext):
        return self.reduce(state, self.readout(r, ctx), r, ctx)

    def finalize(self, state, ctx: LoopContext):
        return {"detector_peak": state}


@pytree
class HangingSleepers:
    """Hanging sleepers' one-sided ballast (added by the loop when the track has them):
    ``support_force`` [n_steps, n_s] N (upwards on each sleeper) and ``sleeper_disp``
    [n_steps, n_s] m (downwards)."""

    def init(self, ctx: LoopContext):
        return ()

    def update(self, state, r: Reading, ctx: LoopContext):
        force, closure = r.support
        return state, {"support_force": force, "sleeper_disp": closure + ctx.supports.gap}

    def finalize(self, state, ctx: LoopContext):
        return {}


@pytree
class OwnCompliance:
    """Each wheel's rail compliance within the step from the kept modes,
    Re sum_r w_r an_r phi_r^2 (``own_compliance`` [n_steps, n_wheels] m/N; for
    :mod:`wfjax.loop.adjoint`)."""

    def init(self, ctx: LoopContext):
        return ()

    def update(self, state, r: Reading, ctx: LoopContext):
        return state, {"own_compliance": r.own_compliance}

    def finalize(self, state, ctx: LoopContext):
        return {}

"""One scenario, one program: :func:`compile_scenario` and the runs every entry point makes.

A :class:`Program` holds a :class:`wfjax.scenario.description.Scenario` prepared for the
devices (:class:`ProgramData`: structure, contact laws, instruments, roughness) and runs it
over a grid of :class:`Run` s. Every run of every entry point is :func:`run_one`: the time
loop (:func:`wfjax.loop.run.time_loop`) of the scenario's wheels with the swept flat's law on
the reference wheel, what to save chosen by a *save* object and, for the fits, how to
differentiate by a *differentiation* object, as ``diffrax.diffeqsolve`` takes ``SaveAt`` and
an adjoint:

- save: :class:`Extremes` (every run's extremes after its run-in: :func:`wfjax.sweep`),
  :class:`Histories` (every step: :func:`wfjax.simulate` and the fits);
- differentiation: :class:`Autodiff` (JAX's reverse and forward modes), :class:`Checkpointed`
  (the runs one after another under ``jax.checkpoint``), :class:`Adjoint` (the hand-written
  reverse mode of :mod:`wfjax.loop.adjoint`).

Grids: :meth:`Program.sweep` (speeds x positions x flats x realisations, chunked and sharded
over the devices, :mod:`wfjax.program.grid`), :meth:`Program.history` (one run),
:meth:`Program.forward` (a rectangular batch of runs for a traced law: the fits).
"""

from __future__ import annotations

import dataclasses
import functools
import sys
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh

from .._parallel import in_background, start_deferred
from .._xla import loop_compiler_options
from ..contact.laws import prepare
from ..contact.table_law import cached_tables_3d
from ..loop.observers import DetectorReadings, Sensors
from ..loop.run import StepOutput, run_scan
from ..loop.setup import widen
from ..loop.structure import structure
from ..params import loop_precision
from ..results import summarise_run
from ..scenario.description import Scenario
from ..scenario.sensors import detector_spec, sensor_spec
from . import grid as grid_mod
from .exported import kept_jit, sharded_program
from .laws import (
    batch_groups,
    loop_roughness,
    padded_models,
    pick_model,
    prepare_batch,
    realisation,
    table_laws,
    table_laws_like,
    vehicle_laws,
)

__all__ = ["Run", "ProgramData", "Program", "compile_scenario", "run_one", "Extremes",
           "Histories", "Autodiff", "Checkpointed", "Adjoint"]


class Run(NamedTuple):
    """One run's numbers (a grid holds [n] of each, in this order).

    ``flat``: index of the swept flat among the program's (int); ``speed`` v [m/s]; ``dt``
    time step [s]; ``x_start`` rail coordinate of the reference wheel at t = 0 [m];
    ``impact_position`` its rail coordinate where its flat strikes [m]; ``run_in``: steps
    before the extremes count; ``end``: the run's own step count (later steps are not
    counted); ``realisation``: roughness/support realisation index (int).
    """

    flat: Any
    speed: Any
    dt: Any
    x_start: Any
    impact_position: Any
    run_in: Any
    end: Any
    realisation: Any


class ProgramData(NamedTuple):
    """What a program's runs read (a pytree of device arrays).

    ``laws``: the swept flats' laws stacked along a leading flat axis; ``others``: [n_wheels]
    the other wheels' fixed laws, None at the reference wheel; ``struct``:
    :class:`wfjax.loop.structure.Structure`; ``sensors``/``detector``: their specs or None;
    ``roughness``: :class:`~wfjax.scenario.patch.LoopRoughness` (realisations along a
    leading axis) or None; ``tracks``: support realisations' padded modal models or None.
    """

    laws: Any
    others: tuple
    struct: Any
    sensors: Any = None
    detector: Any = None
    roughness: Any = None
    tracks: Any = None

    @property
    def flat_wheel(self) -> int:
        """Index of the reference (swept) wheel."""
        return [o is None for o in self.others].index(True)

    def wheel_laws(self, law) -> tuple:
        """[n_wheels] laws: ``law`` (the swept flat's) on the reference wheel, the others'."""
        return tuple(law if o is None else o for o in self.others)


# -- what to save ----------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Extremes:
    """Save every run's extremes after its run-in (and before its own end), by name: ``max``,
    ``min`` [N], ``lost`` (F = 0 occurred), ``lost_t`` [s], ``res`` [m] (largest contact
    residual), ``acc`` [m/s^2] (axle-box peak) of the reference wheel; ``w_max``, ``w_min``,
    ``w_lost``, ``w_acc`` [n_wheels]; ``s_max``, ``s_min`` [n_quantities, n_s] of the
    sensors; ``det`` [n_wheels, n_bays] N of the detector."""

    def observers(self, data: ProgramData, run: Run) -> tuple:
        """The instruments' observers of ``run``, keeping no histories."""
        return tuple(o for o in (
            None if data.sensors is None else Sensors(data.sensors, run.run_in, run.end,
                                                      history=False),
            None if data.detector is None else DetectorReadings(data.detector, run.end,
                                                                history=False)) if o is not None)

    def finalize(self, hist: dict, run: Run, data: ProgramData) -> dict:
        """The run's extremes by name from its histories ``hist`` ([n_steps, n_wheels])."""
        contact = {k: hist[k] for k in ("t",) + StepOutput._fields}
        res = summarise_run(contact, data.flat_wheel, run.speed, run.impact_position, run.dt,
                            run.run_in, end_steps=run.end)
        out = {"w_max": res.wheel_max_force, "w_min": res.wheel_min_force,
               "w_lost": res.wheel_loss_of_contact, "w_acc": res.wheel_axle_acc_peak,
               "max": res.max_force, "min": res.min_force, "lost": res.loss_of_contact,
               "lost_t": res.loss_of_contact_duration, "res": jnp.max(res.residual),
               "acc": res.axle_acc_peak}
        names = {"sensor_max": "s_max", "sensor_min": "s_min", "detector_peak": "det"}
        return out | {short: hist[k] for k, short in names.items() if k in hist}


@dataclasses.dataclass(frozen=True)
class Histories:
    """Save every step: the contact histories [n_steps, n_wheels] (:class:`StepOutput`'s
    fields and ``t``), the sensors' histories and extremes after the run-in, the detector's
    per-bay loads and peaks. ``instruments=False``: the instruments keep their extremes and
    peaks only (a fit's detector)."""

    instruments: bool = True

    def observers(self, data: ProgramData, run: Run) -> tuple:
        """The instruments' observers of ``run``."""
        keep = self.instruments
        return tuple(o for o in (
            None if data.sensors is None else Sensors(data.sensors, run.run_in, history=keep),
            None if data.detector is None else DetectorReadings(data.detector, history=keep))
            if o is not None)

    def finalize(self, hist: dict, run: Run, data: ProgramData) -> dict:
        """The histories as they are."""
        return hist


# -- the run ---------------------------------------------------------------------------------
def run_one(data: ProgramData, law, run: Run, n_steps: int, max_iter: int, precision: str,
            save, n_run=None) -> dict:
    """One run of a program (pure): the time loop of ``n_steps`` steps (static) of every
    wheel, the reference wheel with contact law ``law`` (the swept flat's), on realisation
    ``run.realisation``; ``save`` decides the outputs (:class:`Extremes`,
    :class:`Histories`). ``n_run``: stop after that many steps (traced; forward only)."""
    struct = data.struct
    if data.tracks is not None:  # support realisations: this run's modal model
        struct = struct._replace(track=pick_model(data.tracks, run.realisation))
    hist = run_scan(data.wheel_laws(law), struct, run.speed, run.dt, run.x_start,
                    run.impact_position, n_steps, max_iter,
                    observers=save.observers(data, run), precision=precision,
                    roughness=realisation(data.roughness, run.realisation), n_run=n_run)
    return widen(save.finalize(hist, run, data))  # float64 results from any loop precision


def _picked(data: ProgramData, run: Run, *statics, n_run=None) -> dict:
    """:func:`run_one` with the law of flat ``run.flat`` among ``data.laws``."""
    law = jax.tree.map(lambda a: a[run.flat], data.laws)
    return run_one(data, law, run, *statics, n_run=n_run)


# one run as its own top-level program (a top-level jit may carry compiler options): the
# traced fallback of a kept run (Program.history)
@functools.cache
def _one_run():
    """:func:`run_one` jitted with the backend's loop options (chosen once the backend is)."""
    return jax.jit(run_one, static_argnames=("n_steps", "max_iter", "precision", "save"),
                   compiler_options=loop_compiler_options())


def _local(statics: tuple, data, *columns) -> dict:
    """One device's runs: :func:`_picked` ``vmap``-ed over the run columns ([n] each),
    ``statics`` = (n_steps, max_iter, precision, save). Every device's loop stops at its own
    runs' longest window (``time_loop(n_run=...)``)."""
    runs = Run(*columns)
    n_run = jnp.max(runs.end)
    return jax.vmap(lambda r: _picked(data, r, *statics, n_run=n_run))(runs)


@functools.cache
def _local_of(statics: tuple):
    """:func:`_local` with ``statics`` bound: one function object per statics, so a
    program traced in this process is found again by it."""
    return functools.partial(_local, statics)


def _sweep_program(mesh: Mesh, statics: tuple, data: ProgramData, columns, cache_dir):
    """The sweep's sharded program for arguments shaped as ``data`` and ``columns``: loaded
    from the wfjax cache (:mod:`wfjax.program.exported`), else traced."""
    return sharded_program(_local_of(statics), mesh, statics, data, columns, cache_dir)


# -- how to differentiate a batch of runs (the fits) -------------------------------------------
@dataclasses.dataclass(frozen=True)
class Autodiff:
    """JAX's own reverse and forward modes through the ``vmap``-ed runs."""

    def batch(self, program: Program, data: ProgramData, law, runs: Run, save) -> dict:
        """:func:`run_one` of each of ``runs`` ([B] leaves) with the law ``law`` (shared),
        outputs [B, ...]."""
        return jax.vmap(lambda r: run_one(data, law, r, *program.statics, save))(runs)


@dataclasses.dataclass(frozen=True)
class Checkpointed:
    """The runs one after another, each under ``jax.checkpoint`` (reverse-mode memory: one
    time history at a time)."""

    def batch(self, program: Program, data: ProgramData, law, runs: Run, save) -> dict:
        """As :meth:`Autodiff.batch`, sequentially."""
        return jax.lax.map(
            jax.checkpoint(lambda r: run_one(data, law, r, *program.statics, save)), runs)


@dataclasses.dataclass(frozen=True)
class Adjoint:
    """The hand-written reverse mode of :mod:`wfjax.loop.adjoint` (one ``custom_vjp`` for the
    batch; reverse mode only). Not with the direct 3D mode or hanging sleepers (see
    :mod:`wfjax.loop.adjoint`), nor with support realisations; ``save`` must be
    :class:`Histories`."""

    def batch(self, program: Program, data: ProgramData, law, runs: Run, save) -> dict:
        """As :meth:`Autodiff.batch` (the runs share one realisation and the instruments'
        settings of the first run)."""
        from ..loop.adjoint import run_adjoint_runs

        if not isinstance(save, Histories) or data.tracks is not None:
            raise ValueError("the adjoint saves histories (Histories()) of one track")
        first = jax.tree.map(lambda a: a[0], runs)
        n_steps, max_iter, precision = program.statics
        return run_adjoint_runs(data.wheel_laws(law), data.struct, runs.speed, runs.dt,
                                runs.x_start, runs.impact_position, n_steps, max_iter, precision,
                                realisation(data.roughness, 0), save.observers(data, first))


# -- the program -----------------------------------------------------------------------------
@dataclasses.dataclass
class Program:
    """A scenario prepared for the devices (build with :func:`compile_scenario`).

    ``data`` holds everything but the swept flats' laws (``laws`` None): :meth:`sweep`
    prepares them per group of flats, :meth:`history` its one flat's, a fit traces its own;
    ``n_steps`` is the step count of the batches :meth:`forward` runs (static).
    """

    scenario: Scenario
    data: ProgramData
    cache_dir: Any = None
    n_steps: int = 0

    @property
    def statics(self) -> tuple:
        """(n_steps, max_iter, precision) of :func:`run_one` in the batches :meth:`forward`
        runs for the fits (``"auto"`` precision: float64, as gradients are taken)."""
        config = self.scenario.config
        return (self.n_steps, config.newton_iterations,
                loop_precision(config.precision, gradients=True))

    def history(self, run: Run, save=Histories()) -> dict:
        """One run's outputs (default every step's histories) over its ``run.end`` steps with
        the scenario's only flat, its law prepared eagerly (a batch's laws compile:
        ``prepare_batch``), on the host's default device (``run.flat`` unused); the compiled
        run kept on disk (:func:`wfjax.program.exported.kept_jit`)."""
        sc = self.scenario
        (flat,) = sc.flats
        law = prepare(sc.contact, flat, sc.reference_wheel, sc.track, sc.material, sc.config,
                      self.cache_dir)
        statics = dict(n_steps=int(run.end), max_iter=sc.config.newton_iterations,
                       precision=sc.config.precision, save=save)
        program = kept_jit(functools.partial(run_one, **statics), (self.data, law, run),
                           statics, self.cache_dir, loop_compiler_options(),
                           fallback=functools.partial(_one_run(), **statics))
        return program(self.data, law, run)

    def forward(self, law, runs: Run, save=Histories(), differentiation=Autodiff()) -> dict:
        """The outputs [B, ...] of a rectangular batch of ``runs`` ([B] leaves, every one
        ``self.n_steps`` steps) of the swept flat's law ``law`` (traced geometry), as
        ``differentiation`` differentiates them."""
        return differentiation.batch(self, self.data, law, runs, save)

    def sweep(self, speeds: np.ndarray, positions: np.ndarray, chunk_size=None,
              progress: bool = True, save=Extremes(), ahead=None) -> dict[str, np.ndarray]:
        """Every flat x speed x position x realisation's outputs by name, [n_flats,
        n_speeds, n_positions, R, ...], each run with :func:`wfjax.simulate`'s window and time
        step (:func:`wfjax.program.grid.plan_runs`), chunked and sharded over the devices."""
        return _Sweep(self, speeds, positions, chunk_size, progress, save, ahead).run()


def compile_scenario(scenario: Scenario, cache_dir=None) -> Program:
    """The :class:`Program` of ``scenario``: the structure of its vehicle on its track (modal
    models cached on disk in ``cache_dir``), the other wheels' laws, the instruments' specs,
    the loop roughness and, with support realisations, their padded modal models."""
    sc = scenario
    struct = structure(sc.vehicle, list(sc.wheels), sc.track, sc.config, cache_dir)
    models = None
    if sc.tracks is not None:
        models = padded_models(sc.tracks, sc.config, cache_dir)
        struct = struct._replace(track=pick_model(models, 0))
    fw = sc.vehicle.flat_wheel
    flats = [None if i == fw else f for i, f in enumerate(sc.vehicle_flats(sc.flats[0]))]
    others = vehicle_laws(sc.contact, flats, list(sc.wheels), sc.track, sc.material, sc.config,
                          cache_dir)  # the reference wheel's law: per flat, None here
    sensors = (None if sc.sensors is None else sensor_spec(sc.sensors, sc.track, struct.track,
                                                           sc.sensor_quantities))
    detector = None if sc.detector is None else detector_spec(sc.detector, sc.track,
                                                              struct.track)
    rough = loop_roughness(sc.roughness, sc.wheel_roughness, list(sc.wheels), sc.track,
                           sc.material)
    return Program(sc, ProgramData(None, others, struct, sensors, detector, rough, models),
                   cache_dir)


def tables_ahead(scenario: Scenario, cache_dir=None) -> dict:
    """The exact 3D tables of each of ``scenario``'s table groups (:func:`batch_groups`),
    built in background threads: ``{flat indices: future of the tables}``. They need no
    track, so a sweep starts them before its modal model and its program, which build
    alongside (:meth:`Program.sweep`'s ``ahead``)."""
    sc = scenario
    return {tuple(g.indices): in_background(
        cached_tables_3d, [sc.flats[i] for i in g.indices], float(sc.reference_wheel.radius),
        float(sc.track.rail_head_radius), sc.material, sc.config.contact_element, cache_dir)
        for g in batch_groups(sc.flats, sc.contact, sc.config) if g.tables}


class _Sweep:
    """:meth:`Program.sweep`'s work: per group of flats, its laws, runs and chunks."""

    def __init__(self, program: Program, speeds, positions, chunk_size, progress, save,
                 ahead=None):
        self.program, self.v, self.pos = program, np.asarray(speeds), np.asarray(positions)
        self.ahead = ahead
        self.chunk_size, self.progress, self.save = chunk_size, progress, save
        self.mesh = grid_mod.device_mesh()
        self.data = grid_mod.replicate(program.data, self.mesh)

    def run(self) -> dict[str, np.ndarray]:
        sc = self.program.scenario
        groups = batch_groups(sc.flats, sc.contact, sc.config)
        if self.progress and any(g.tables for g in groups):
            print("  building the 3D contact tables (cached after the first run) ...",
                  end="\r", file=sys.stderr, flush=True)
        ahead = self.ahead if self.ahead is not None else tables_ahead(sc, self.program.cache_dir)
        out = {}
        for group in groups:
            for key, col in self._group(group, ahead.get(tuple(group.indices))).items():
                out.setdefault(key, np.zeros((len(sc.flats),) + col.shape[1:],
                                             col.dtype))[group.indices] = col
        return out

    def _label(self, members, tables: bool) -> str:
        if len(members) == 1:
            from ..results import flat_label

            return flat_label(members[0])
        return f"{len(members)} flats" if tables else f"{len(members)} {members[0].kind} flats"

    def _group(self, group, tables_ahead) -> dict[str, np.ndarray]:
        sc, program = self.program.scenario, self.program
        members = [sc.flats[i] for i in group.indices]
        label = self._label(members, group.tables)
        if self.progress:  # a 3D table or family build takes seconds to a minute, cold
            what = "3D contact tables" if group.tables else f"{sc.contact} contact law"
            print(f"  {label}: preparing the {what} ...", end="\r", file=sys.stderr,
                  flush=True)
        compiled = None
        if group.tables:  # compile for the tables' shapes while they are being built
            laws, sizing = table_laws_like(members, sc.reference_wheel, sc.track, sc.material,
                                           sc.config), members
        else:
            laws, sizing = prepare_batch(sc.contact, members, sc.reference_wheel, sc.track,
                                         sc.material, sc.config, program.cache_dir,
                                         self.progress)
        windows = [sc.window_flat(w) for w in sizing]
        for w in windows:
            sc.check_settings(w, self.v, self.pos)
        runs = grid_mod.plan_runs(windows, self.v, self.pos + sc.shift, program.data.struct,
                                  sc.config, self.mesh, self.chunk_size, sc.n_realisations)
        statics = (runs.n_steps, sc.config.newton_iterations, sc.config.precision, self.save)
        data = self.data._replace(laws=grid_mod.replicate(laws, self.mesh))
        first = grid_mod.chunk(runs, 0, self.mesh)[1]
        fn = _sweep_program(self.mesh, statics, data, first, program.cache_dir)
        start_deferred()  # traced: XLA compiles next, the GIL is free
        if group.tables:
            compiled = fn.lower(data, *first).compile()
            like, laws = laws, table_laws(tables_ahead.result())
            data = self.data._replace(laws=grid_mod.replicate(laws, self.mesh))
            if jax.tree.map(np.shape, laws) != jax.tree.map(np.shape, like):
                compiled = None  # not the shapes it was compiled for: compile as usual
        bar = grid_mod.Progress(runs.columns[0].size, label, enabled=self.progress)
        return grid_mod.run_chunks(compiled or fn, data, runs, self.mesh, bar)

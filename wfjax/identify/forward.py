"""The identification's forward model: detector readings [N] of wheels with flats, through the
program core (:func:`wfjax.program.core.compile_scenario`, ``Program`` data, the batched runs
of :class:`wfjax.program.core.Autodiff`).

Two levels:

* :func:`build_table`: the **response table** of one wheel at one speed. One single-wheel
  scenario with a wide detector (the impact bay and the 4 after it), compiled once; one
  ``vmap``-ed batch per flat shape over lengths x in-bay impact positions x nuisance
  realisations (rail roughness of the ISO 3095 limit class, and support scatter, each
  realisation its own program's data). The track is periodic in the sleeper spacing L_S, so
  an impact at rail coordinate x = q L_S + u reads in detector bay k what the table holds at
  bay offset k - q and position u (:func:`wfjax.identify.prediction.predict`, every strike
  of the flat from the last at or before the bay): the phase is a grid over a whole wheel
  circumference, evaluated from one bay's runs.
* :func:`coupled_readings`: several wheels of a bogie on one track, every wheel its own
  flat and impact coordinate (the vehicle's ``flat_delays``), run in full: the synthetic
  passages of the validation, and the neighbour correction of the factorised inference.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import time

import jax
import jax.numpy as jnp
import numpy as np

from .._cache import load_or_build
from ..params import Flat, Material, SimConfig, Track, Wheel
from ..program.core import Autodiff, Histories, Run, compile_scenario, run_one
from ..scenario.description import Scenario
from ..scenario.sensors import Detector
from ..scenario.windows import batch_windows
from .table3d import PROGRAMS as _PROGRAMS
from .table3d import stacked_laws, table_batch_3d

__all__ = ["SMOOTH_LENGTH", "round_wheel", "SHAPES", "TABLE_LENGTHS", "TABLE_BAYS",
           "ResponseTable", "flat_of", "build_table", "coupled_readings", "coupled_batch",
           "identification_config", "extent_bound", "CORRECTION_TRACK"]

_log = logging.getLogger(__name__)
SMOOTH_LENGTH = 4e-3  # m: a round wheel's stand-in flat (new, depth 4.4 um at R 0.45 m): no impact
SHAPES = (("new", 0.0), ("rounded", 1.6), ("rounded", 1.8), ("rounded", 2.0))  # (kind, l/l0)
TABLE_LENGTHS = np.array([5, 12, 20, 28, 36, 45, 55, 65, 75, 87, 100, 115, 130]) * 1e-3  # m
# bays the table holds: the impact bay and the 4 after it. A flat strikes every 2 pi R
# (4.35 L_S for a 0.45 m wheel), so every detector bay lies 0..4 bays after its last strike
TABLE_BAYS = 5
ROUGHNESS_SPAN = 24.0  # m of generated rail roughness, centred on x = 0
# impact positions per bay in the table, 32.5 mm apart at L_S = 0.65 m: a 0.45 m wheel's
# circumference is then 87.0 positions (0.1 mm off), so every strike lies on one
N_OFFSETS = 20
# m of travel before a table run's impact at least (the detector's first bay is the impact
# bay): its readings and peak force within 0.3 % of runs begun a circumference earlier
TABLE_RUN_IN = 1.3
# the track the identification was built and validated on (docs/identify.md: 70 bays hold a
# bogie's windows over the 5-bay detector with support scatter, whose per-sleeper arrays fix
# the length): the defaults before 2026-12-03, with absorbing ends (the default until
# 2026-12-06). Moving it to today's defaults (26 el./bay, end networks, lengthened) rebuilds
# every table and needs the validation study run again.
TRACK = Track(n_bays=70, elements_per_bay=8, ends="absorbing")
# TRACK at its least length with end networks, for the neighbour corrections' coupled runs
# (no support scatter, so the guards lengthen it: 24 bays over the 5-bay detector; 36 with
# TRACK's absorbing ends, the corrections' track until 2026-12-06). A correction is a
# difference of two runs on it; it reads within 0.5 % of the largest reading of TRACK's on
# the study's 60-140 km/h (tests/test_identify.py; docs/identify.md "Several wheels")
CORRECTION_TRACK = dataclasses.replace(TRACK, n_bays=4, ends="network")


def identification_config(config: SimConfig | None = None) -> SimConfig:
    """``config`` (default :class:`SimConfig`) with its auto settings resolved for a detector's
    reading (:data:`wfjax.params.READING_SETTINGS`: modes to 15 kHz, a 25 us step cap and a
    float64 loop, as ``wfjax detector`` runs; its studies ran at 20 kHz without the track's
    damper augmentation, docs/identify.md)."""
    return (config or SimConfig()).resolved(reading=True)


def flat_of(kind: str, length, length_factor: float, wheel_radius: float,
            extent_bound: float | None = None) -> Flat:
    """The flat of ``kind`` and length ``length`` [m] (traceable): new, depth l^2 / (8 R);
    rounded of l / l0 = ``length_factor``, depth (l / factor)^2 / (8 R)."""
    if kind == "new":
        return Flat("new", depth=length**2 / (8 * wheel_radius), length=length,
                    wheel_radius=wheel_radius, extent_bound=extent_bound)
    depth = (length / length_factor) ** 2 / (8 * wheel_radius)
    return Flat("rounded", depth=depth, length=length, wheel_radius=wheel_radius,
                extent_bound=extent_bound)


def round_wheel(wheel_radius: float) -> Flat:
    """A round wheel's stand-in :class:`Flat` (new, :data:`SMOOTH_LENGTH`) of radius
    ``wheel_radius`` [m]: the loop needs a flat on every wheel."""
    return flat_of("new", SMOOTH_LENGTH, 1.0, wheel_radius)


def extent_bound(wheel_radius: float, shapes=SHAPES, lengths=TABLE_LENGTHS) -> float:
    """The largest half extent [m] of the ``shapes``' flats up to the longest of ``lengths``
    [m]: the common ``extent_bound`` that sizes every parametric flat's contact tables alike,
    so one compiled program serves every flat length (a table sized by each flat's own extent
    would recompile the program for every flat)."""
    top = float(np.max(lengths))
    return max(float(flat_of(kind, top, factor, wheel_radius).half_extent)
               for kind, factor in shapes)


def _bounded(flat: Flat, wheel_radius: float) -> Flat:
    """``flat`` with :func:`extent_bound` when it is parametric (new or rounded), unbounded and
    within the bound; other flats unchanged."""
    if flat.kind not in ("new", "rounded") or flat.extent_bound is not None:
        return flat
    bound = extent_bound(wheel_radius)
    return dataclasses.replace(flat, extent_bound=bound) if flat.half_extent <= bound else flat


def depth_of(kind: str, length, length_factor: float, wheel_radius: float):
    """Depth [m] of :func:`flat_of`'s flat (numpy broadcasting)."""
    l0 = length if kind == "new" else length / length_factor
    return np.asarray(l0) ** 2 / (8 * wheel_radius)


@dataclasses.dataclass(frozen=True)
class ResponseTable:
    """One wheel's detector response at one speed.

    Attributes:
        speed: v [m/s]. sleeper_spacing: L_S [m]. wheel_radius: R [m].
        shapes: [S] (kind, l / l0) of the flat shapes. lengths: [L] flat lengths [m].
        offsets: [J] impact positions u within a bay [m], j L_S / J.
        readings: [S, L, J, R, TABLE_BAYS] bay readings [N] at bay offsets
            0..TABLE_BAYS - 1 from the impact bay (one strike), over R nuisance realisations.
        peak: [S, L, J, R] the wheel's peak contact force [N] after the run-in.
    """

    speed: float
    sleeper_spacing: float
    wheel_radius: float
    shapes: tuple
    lengths: np.ndarray
    offsets: np.ndarray
    readings: np.ndarray
    peak: np.ndarray

    @property
    def n_realisations(self) -> int:
        return int(self.readings.shape[3])


def _nuisance_programs(ref: Flat, contact: str, detector: Detector, track: Track,
                       wheel: Wheel, material: Material, config: SimConfig,
                       n_rough: int, n_supports: int, scatter_cv: float, seed: int, cache_dir):
    """[n_supports] (program, device data) of the single wheel, each with ``n_rough`` rail
    roughness realisations (ISO 3095 limit) and its own support scatter (the first: none
    when ``n_supports`` is 1)."""
    from ..model.supports import scatter
    from ..scenario import roughness as rough_mod

    out = []
    for k in range(n_supports):
        tr = track if (n_supports == 1 or scatter_cv <= 0) else scatter(
            track, seed + 1000 + k, scatter_cv)
        rough = rough_mod.generate(rough_mod.ISO3095_LIMIT, seed + k, ROUGHNESS_SPAN,
                                   x_start=-ROUGHNESS_SPAN / 2, n_realisations=n_rough)
        sc = Scenario.of(ref, contact, wheel=wheel, track=tr, material=material,
                         config=config, detector=detector, roughness=rough)
        prog = compile_scenario(sc, cache_dir)
        data = jax.tree.map(lambda a: jnp.asarray(a) if isinstance(a, np.ndarray) else a,
                            prog.data)
        out.append((prog, data))
    return out


def _runs(program, window: Flat, speed: float, positions: np.ndarray, n_rough: int) -> Run:
    """[J x R] runs (positions x realisations) of one speed; sets ``program.n_steps``."""
    n_steps, dt, s0, run_in = batch_windows(window, np.array([speed]), program.scenario.config)
    program.n_steps = int(n_steps)
    pp = np.repeat(positions, n_rough)
    rr = np.tile(np.arange(n_rough), positions.size)
    n = pp.size
    cols = (np.zeros(n, int), np.full(n, speed), np.full(n, dt[0]), pp + s0[0], pp,
            np.full(n, run_in[0]), np.full(n, n_steps), rr)
    return Run(*(jnp.asarray(c) for c in cols))


@functools.partial(jax.jit, static_argnames=("key",))
def _table_batch(data, runs, lengths, factor, key):
    """[n_lengths, B, n_bays] detector peaks and [n_lengths, B] peak forces [N] of the flats
    of ``lengths`` [m] (shape ``key``'s kind, l / l0 = ``factor`` traced)."""
    program, law_of = _PROGRAMS[key]
    kind, radius, bound = key[1], key[2], key[3]

    def one(length):
        law = law_of(flat_of(kind, length, factor, radius, bound))
        out = Autodiff().batch(program, data, law, runs, Histories(instruments=False))
        after = jnp.arange(out["force"].shape[1])[None, :] >= runs.run_in[:, None]
        return out["detector_peak"][:, 0], jnp.max(jnp.where(after, out["force"][..., 0], 0.0),
                                                    axis=-1)

    return jax.lax.map(one, lengths)




def _laws_3d(contact, shapes, lengths, radius, bound, track, material, config, cache_dir):
    """None, or with ``contact="3d"`` per shape the stacked exact 3D tables of its flats of
    ``lengths`` (:func:`wfjax.identify.table3d.stacked_laws`), widened to at least the
    longest parametric flats' column count (as :func:`coupled_batch` widens them)."""
    if contact != "3d":
        return None
    top = [flat_of(k, float(TABLE_LENGTHS[-1]), f, radius) for k, f in SHAPES]
    return stacked_laws([[flat_of(k, float(x), f, radius, bound) for x in lengths]
                         for k, f in shapes], radius, track, material, config, cache_dir,
                        sizing=top)


def build_table(speed: float, contact: str = "hertz-trajectory", gauge_offset: float = 0.1,
                calibration: float = 1.0, shapes=SHAPES, lengths=TABLE_LENGTHS,
                n_offsets: int = N_OFFSETS, n_roughness: int = 3, n_supports: int = 1,
                scatter_cv: float = 0.1, seed: int = 0, wheel: Wheel | None = None,
                track: Track | None = None, material: Material | None = None,
                config: SimConfig | None = None, cache_dir=None, progress=None
                ) -> ResponseTable:
    """The :class:`ResponseTable` of one wheel at ``speed`` [m/s] (cached on disk).

    Runs S shapes x L ``lengths`` [m] x ``n_offsets`` in-bay impact positions x
    (``n_roughness`` x ``n_supports``) nuisance realisations; ``progress(done, total)`` is
    called after every shape and support realisation. The cache key holds the speed rounded
    to 1e-9 m/s (100 / 3.6 and 27.777777778 find the same table) and ``contact``, the
    contact law: ``"hertz-trajectory"`` (the default; traced in the length), ``"3d"`` (every
    flat's exact 3D table, Kalker, widened to one column count: :mod:`.table3d`) or another
    registered model (its traced law; untried). An unknown ``contact`` is a one-line
    ``ValueError`` naming it.
    """
    from ..contact.registry import check
    from ..fit.models import TracedLaw

    check(contact)
    wheel, track = wheel or Wheel(), track or TRACK
    material, config = material or Material(), identification_config(config)
    config = dataclasses.replace(config, run_in=max(config.run_in, TABLE_RUN_IN))
    key = dict(speed=round(float(speed), 9), contact=contact, g=float(gauge_offset),
               c=float(calibration), shapes=[list(s) for s in shapes],
               lengths=np.asarray(lengths), j=int(n_offsets), r=int(n_roughness),
               s=int(n_supports), cv=float(scatter_cv), seed=int(seed), wheel=repr(wheel),
               track=repr(track), material=repr(material), config=repr(config),
               v=4)  # 2: the rail's in-element deflection (2026-12-03); 3: the track's
    # damper augmentation of its truncated modes (2026-12-05: the readings move); 4: the
    # impact bay and the 4 after it (every strike, 2026-12-05; were bays -2..+2)
    if contact == "3d":  # the exact tables' builder (Hertz-trajectory keys unchanged)
        from ..contact.table_law import TABLE_BUILDER_REVISION
        key |= dict(law="exact-3d-tables", table3d=TABLE_BUILDER_REVISION)
    ls = float(track.sleeper_spacing)
    offsets = np.arange(n_offsets) * ls / n_offsets
    radius = float(wheel.radius)

    def build():
        det = Detector(TABLE_BAYS, 0, float(gauge_offset), float(calibration))
        total, done = len(shapes) * n_supports, 0
        reads = np.zeros((len(shapes), len(lengths), n_offsets, n_supports, n_roughness,
                          TABLE_BAYS))
        peaks = np.zeros(reads.shape[:-1])
        bound = max(float(flat_of(kind, float(np.max(lengths)), factor, radius).half_extent)
                    for kind, factor in shapes)
        first = flat_of(shapes[0][0], float(np.max(lengths)), shapes[0][1], radius, bound)
        programs = _nuisance_programs(first, contact, det, track, wheel, material, config,
                                      n_roughness, n_supports, scatter_cv, seed, cache_dir)
        laws3d = _laws_3d(contact, shapes, lengths, radius, bound, track, material, config,
                          cache_dir)
        for s, (kind, factor) in enumerate(shapes):
            ref = flat_of(kind, float(np.max(lengths)), factor, radius, bound)
            for k, (prog, data) in enumerate(programs):
                runs = _runs(prog, prog.scenario.window_flat(ref), float(speed), offsets,
                             n_roughness)
                pkey = (contact, "table" if laws3d else kind, radius, bound, prog.statics,
                        n_supports > 1)
                if pkey not in _PROGRAMS:
                    _PROGRAMS[pkey] = (prog, None if laws3d else TracedLaw.of(
                        prog.scenario, ref, cache_dir))
                if laws3d:
                    r, p = table_batch_3d(data, runs, laws3d[s], pkey)
                else:
                    r, p = _table_batch(data, runs, jnp.asarray(lengths), float(factor), pkey)
                shape = (len(lengths), n_offsets, n_roughness)
                reads[s, :, :, k] = np.asarray(r).reshape(shape + (-1,))
                peaks[s, :, :, k] = np.asarray(p).reshape(shape)
                done += 1
                if progress:
                    progress(done, total)
        return {"readings": reads.reshape(reads.shape[:3] + (-1, TABLE_BAYS)),
                "peak": peaks.reshape(peaks.shape[:3] + (-1,))}

    arrays = load_or_build("identify-table", key, build, cache_dir)
    return ResponseTable(float(speed), ls, radius, tuple(tuple(s) for s in shapes),
                         np.asarray(lengths, float), offsets, arrays["readings"],
                         arrays["peak"])


def _window(detector: Detector, track: Track, wheel: Wheel, config: SimConfig, positions,
            speed: float) -> tuple[float, float, int, int]:
    """(x_start [m], dt [s], n_steps, run_in steps) of a coupled run: a window fixed by the
    detector and the layout (one compiled step count for every phase): every wheel starts a
    bay and a run-in before the first gauge and ends past the last."""
    a, b = detector.gauges(float(track.sleeper_spacing))
    ls = float(track.sleeper_spacing)
    lead_in = max(config.run_in, 0.3)
    x0 = min(float(a[0]) - ls - 2 * math.pi * float(wheel.radius), float(a[0])) - lead_in
    x1 = float(b[-1]) + 0.3 + float(positions[-1] - positions[0])
    dt = config.time_step_for(float(speed))
    n_steps = int(math.ceil((x1 - x0) / (speed * dt))) + 1
    run_in = int(np.floor(0.5 * 0.02 / dt))
    return x0, dt, n_steps, run_in


@functools.partial(jax.jit, static_argnames=("statics",))
def _coupled_batch(data, law, runs, statics):
    """Detector peaks [B, n_wheels, n_bays] and peak forces [B, n_wheels] [N] of ``runs``."""
    holder = _Statics(statics)
    out = Autodiff().batch(holder, data, law, runs, Histories(instruments=False))
    after = jnp.arange(out["force"].shape[1])[None, :, None] >= runs.run_in[:, None, None]
    return out["detector_peak"], jnp.max(jnp.where(after, out["force"], 0.0), axis=1)


@dataclasses.dataclass(frozen=True)
class _Statics:
    statics: tuple


def coupled_readings(flats, impacts, positions, speed: float, detector: Detector,
                     contact: str = "hertz-trajectory", roughness=None,
                     track: Track | None = None, wheel: Wheel | None = None,
                     material: Material | None = None, config: SimConfig | None = None,
                     cache_dir=None, repeat_flats: bool = True
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Readings [n, n_bays] N and peak contact forces [n] N of ``n`` coupled wheels (a bogie)
    on one track, every wheel with its own flat, in one run.

    Args:
        flats: [n] :class:`Flat` per wheel (a round wheel: :func:`round_wheel`).
        impacts: [n] rail coordinate [m] where each wheel's flat strikes (x = 0 the sleeper at
            the start of bay 0), within the detector's reach.
        positions: [n] distance of each wheel behind the group's leading wheel [m].
        speed: v [m/s]. detector: the :class:`Detector` (absolute bays).
        roughness: one rail :class:`wfjax.Roughness` realisation (values [n]) or None.
        track: the track (may carry support scatter).
        repeat_flats: every flat strikes once per revolution, as on a real wheel
            (:attr:`wfjax.model.vehicle.Vehicle.repeat_flats`): at its impact coordinate and
            every 2 pi R before and after it within the run's window (which starts a bay and a
            circumference before the detector); the peak contact force is the largest of
            them. False: at its impact coordinate only (a response table's single strike).
    """
    from ..contact.laws import prepare
    from ..model.vehicle import Vehicle

    wheel, track = wheel or Wheel(), track or TRACK
    material, config = material or Material(), identification_config(config)
    positions = np.asarray(positions, float)
    impacts = np.asarray(impacts, float)
    flats = [_bounded(f, float(wheel.radius)) for f in flats]
    offsets = positions[0] - positions
    delays = impacts - impacts[0] - offsets
    ref = flats[0]
    vehicle = Vehicle(tuple(positions), flats=tuple(flats), flat_wheel=0,
                      flat_delays=tuple(delays), repeat_flats=repeat_flats)
    sc = Scenario.of(ref, contact, wheel=wheel, track=track, material=material, config=config,
                     vehicle=vehicle, detector=detector, roughness=roughness)
    prog = compile_scenario(sc, cache_dir)
    data = jax.tree.map(lambda a: jnp.asarray(a) if isinstance(a, np.ndarray) else a, prog.data)
    x0, dt, n_steps, run_in = _window(detector, track, wheel, config, positions, speed)
    run = Run(*(jnp.asarray([c]) for c in (0, float(speed), dt, x0, float(impacts[0]), run_in,
                                           n_steps, 0)))
    law = prepare(contact, ref, sc.reference_wheel, sc.track, material, sc.config, cache_dir)
    statics = (n_steps, sc.config.newton_iterations, sc.config.precision)
    t0 = time.perf_counter()
    peaks, force = _coupled_batch(data, law, run, statics)
    peaks.block_until_ready()
    _log.debug("coupled run %.1f s", time.perf_counter() - t0)
    return np.asarray(peaks[0]), np.asarray(force[0])


@functools.partial(jax.jit, static_argnames=("treedef", "statics"))
def _bogie_batch(data, leaves, runs, treedef, statics):
    """Detector peaks [B, n_wheels, n_bays] and peak forces [B, n_wheels] [N] of B groups of
    one program: ``leaves`` of (reference law, the other wheels' laws, flat delays), each
    stacked along a leading axis [B], rebuilt by ``treedef``."""
    save = Histories(instruments=False)

    def one(own, run):
        law, others, delays = jax.tree.unflatten(treedef, own)
        d = data._replace(others=others, struct=data.struct._replace(delays=delays))
        out = run_one(d, law, run, *statics, save)
        after = jnp.arange(out["force"].shape[0])[:, None] >= run.run_in
        return out["detector_peak"], jnp.max(jnp.where(after, out["force"], 0.0), axis=0)

    return jax.vmap(one)(list(leaves), runs)


# Compiled batches kept at most: every layout, track, law structure and batch size is a
# program of its own, and each holds its machine code in memory maps; a process that
# identified train after train (a study, a wayside service) grew by about 1,000 maps per
# program until the kernel's limit (vm.max_map_count, 65,530) ended it after 22 wagons.
MAX_BATCH_PROGRAMS = 16


def _bounded_programs() -> None:
    """Drop :func:`_bogie_batch`'s compiled programs once it holds MAX_BATCH_PROGRAMS (a
    persistent compilation cache, as the ``wfjax`` command enables, reloads them)."""
    if _bogie_batch._cache_size() >= MAX_BATCH_PROGRAMS:
        _bogie_batch.clear_cache()


def _padded(n: int) -> int:
    """The batch size that runs ``n`` groups: a power of two up to 8, then a multiple of 8 (a
    compiled batch serves every count that pads to its size)."""
    return 1 << (n - 1).bit_length() if n <= 8 else -(-n // 8) * 8


def _group_laws(flats, sc: Scenario, contact: str, cache_dir) -> tuple:
    """(the first wheel's law, the other wheels' laws) of one group's ``flats``."""
    from ..contact.laws import prepare
    from ..program.laws import vehicle_laws

    return (prepare(contact, flats[0], sc.reference_wheel, sc.track, sc.material, sc.config,
                    cache_dir),
            vehicle_laws(contact, [None] + list(flats[1:]), list(sc.wheels), sc.track,
                         sc.material, sc.config, cache_dir))


def _common_columns(laws, sc: Scenario):
    """``laws`` with every exact 3D table (:class:`wfjax.contact.table_law.TableLaw`) widened
    to one column count (:func:`wfjax.contact.interpolation.pad_columns`: the same forces),
    at least that of the longest parametric flat (:data:`TABLE_LENGTHS`' last), so that the
    groups of one call stack into one batch and one compiled program serves every call;
    other laws unchanged."""
    from ..contact.interpolation import pad_columns
    from ..contact.table_law import TableLaw, table_specs_3d

    def is_table(x):
        return isinstance(x, TableLaw)

    tables = [x for pair in laws for x in jax.tree.leaves(pair, is_leaf=is_table)
              if is_table(x)]
    if not tables:
        return laws
    radius = float(sc.reference_wheel.radius)
    top = [flat_of(k, float(TABLE_LENGTHS[-1]), f, radius) for k, f in SHAPES]
    n_s = max([sp.n_s for sp in table_specs_3d(top, radius, float(sc.track.rail_head_radius),
                                               sc.material, sc.config.contact_element)] +
              [int(np.shape(t.table.onset)[0]) for t in tables])
    return [jax.tree.map(lambda x: TableLaw(pad_columns(x.table, n_s)) if is_table(x) else x,
                         pair, is_leaf=is_table) for pair in laws]


def coupled_batch(groups, positions, speed: float, detector: Detector,
                  contact: str = "hertz-trajectory", roughness=None, track: Track | None = None,
                  wheel: Wheel | None = None, material: Material | None = None,
                  config: SimConfig | None = None, cache_dir=None, repeat_flats: bool = True
                  ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`coupled_readings` of ``B`` groups of wheels (bogies) of one layout on one track
    and rail, each with its own flats and impacts, batched: readings [B, n, n_bays] N and peak
    contact forces [B, n] N.

    Args:
        groups: [B] (flats [n], impacts [n]) per group, as :func:`coupled_readings` takes them.
        positions: [n] the layout every group shares [m] (0 first).
        The rest as :func:`coupled_readings` (every strike by default): one track (support
        scatter included) and one rail ``roughness`` realisation for every group (one
        detector site).

    One program is compiled for the layout (:func:`compile_scenario` once, not per group); a
    group's flats enter only as its wheels' contact laws and flat delays, which are stacked
    along a batch axis and ``vmap``-ed with the group's impact coordinate. Groups whose laws
    share one pytree structure (the same flat kind on every wheel: a round wheel is a new
    4 mm flat) run as one batch, padded (:func:`_padded`) so that one compiled batch serves
    several group counts; usually one to three batches per call.
    """
    from ..model.vehicle import Vehicle

    wheel, track = wheel or Wheel(), track or TRACK
    material, config = material or Material(), identification_config(config)
    positions = np.asarray(positions, float)
    offsets = positions[0] - positions
    radius = float(wheel.radius)
    cases = []
    for flats, impacts in groups:
        impacts = np.asarray(impacts, float)
        if len(flats) != positions.size or impacts.size != positions.size:
            raise ValueError(f"coupled_batch: a group of {len(flats)} flats and {impacts.size} "
                             f"impacts; the layout has {positions.size} wheels")
        cases.append(([_bounded(f, radius) for f in flats], impacts,
                      impacts - impacts[0] - offsets))
    n_bays = detector.n_bays
    if not cases:
        return np.zeros((0, positions.size, n_bays)), np.zeros((0, positions.size))
    f0, _, d0 = cases[0]
    vehicle = Vehicle(tuple(positions), flats=tuple(f0), flat_wheel=0, flat_delays=tuple(d0),
                      repeat_flats=repeat_flats)
    sc = Scenario.of(f0[0], contact, wheel=wheel, track=track, material=material, config=config,
                     vehicle=vehicle, detector=detector, roughness=roughness)
    prog = compile_scenario(sc, cache_dir)
    # the other wheels' laws come per group (the batch's leaves): the first group's would
    # carry its flat kinds into the program's signature and compile it again for each
    data = jax.tree.map(lambda a: jnp.asarray(a) if isinstance(a, np.ndarray) else a,
                        prog.data._replace(others=None))
    x0, dt, n_steps, run_in = _window(detector, track, wheel, config, positions, speed)
    statics = (n_steps, sc.config.newton_iterations, sc.config.precision)
    by_tree: dict = {}
    laws = _common_columns([_group_laws(f, sc, contact, cache_dir) for f, _, _ in cases], sc)
    for b, ((_, impacts, delays), (law, others)) in enumerate(zip(cases, laws,
                                                                       strict=True)):
        leaves, treedef = jax.tree.flatten((law, others, delays))
        by_tree.setdefault(treedef, []).append((b, leaves, float(impacts[0])))
    peaks = np.zeros((len(cases), positions.size, n_bays))
    force = np.zeros((len(cases), positions.size))
    t0 = time.perf_counter()
    for treedef, members in by_tree.items():
        idx = [m[0] for m in members]
        size = _padded(len(members))
        pad = members + [members[0]] * (size - len(members))
        cols = zip(*(m[1] for m in pad), strict=True)
        leaves = [jnp.stack([jnp.asarray(x) for x in c]) for c in cols]
        runs = Run(*(jnp.asarray(c) for c in (
            np.zeros(size, int), np.full(size, float(speed)), np.full(size, dt),
            np.full(size, x0), np.array([m[2] for m in pad]), np.full(size, run_in),
            np.full(size, n_steps), np.zeros(size, int))))
        _bounded_programs()
        p, f = _bogie_batch(data, leaves, runs, treedef, statics)
        peaks[idx], force[idx] = np.asarray(p)[:len(idx)], np.asarray(f)[:len(idx)]
    _log.debug("coupled batch of %d groups: %.1f s", len(cases), time.perf_counter() - t0)
    return peaks, force

"""Batched simulations: speeds x impact positions (x flats), ``vmap``-ed and chunked.

The runs of a group of flats (:func:`batch_groups`: one kind with a traced law, or every flat
with an exact 3D table) share one compiled program. Every run has the window, step count and
time step :func:`wfjax.simulate` gives it (a kind's traced flats: the window of the group's
largest; a flat with an exact table: its own), so a sweep's run equals that ``simulate``. The
program's histories have the largest step count; the runs are sorted by their own, and each
chunk's loop stops at its longest run (``time_loop(n_run=...)``; the steps after a run's window
are not counted in its summaries). The batch
is cut into chunks sized for the devices (:func:`chunk_width`: from the device's free memory
and the program's bytes per run, capped where more runs no longer raise throughput) and
progress with an ETA is printed per chunk. Chunks are dispatched ahead: chunk k + 1 is queued
on the devices before chunk k's summaries are copied to the host, so the devices never wait
for the host between chunks.

Devices: each chunk is sharded over every JAX device (``jax.devices()``) along the flattened
run axis with a one-axis :class:`jax.sharding.Mesh` (axis ``"runs"``) and a
:class:`jax.sharding.NamedSharding`; the model parameters are replicated. A chunk is padded to
a multiple of the device count (padding repeats the last run and is dropped afterwards).
Runs are independent, so the results equal the single-device ones. On a CPU,
``XLA_FLAGS=--xla_force_host_platform_device_count=N`` exposes N devices. Multi-host: call
:func:`jax.distributed.initialize` in every process before the sweep and run the same sweep
everywhere; ``jax.devices()`` then spans all hosts and every process receives the full result
(``benchmarks/multihost_example.py``).
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import io
import json
import math
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from . import supports as supports_mod
from ._parallel import in_background
from ._xla import LOOP_COMPILER_OPTIONS, to_device
from .api import loop_roughness, vehicle_laws
from .contact import registry
from .contact.laws import prepare, prepare_family, resolve_mode_3d
from .contact.table_law import TableLaw, cached_tables_3d, table_specs_3d
from .contact.tables import ContactTable, pad_columns
from .loop.observers import DetectorReadings, Sensors
from .loop.run import StepOutput, run_scan
from .loop.structure import structure, vehicle_structure
from .params import Flat, Material, SimConfig, Track, Wheel
from .results import summarise, summarise_vehicle
from .scenario.windows import (
    check_impact_positions,
    check_rail_span,
    check_speeds,
    detector_config,
    impact_positions_grid,
    run_windows,
    simulation_window,
    vehicle_window_flat,
    wheel_positions,
)
from .sensors import QUANTITIES, detector_spec, sensor_spec
from .vehicle import check_on_track
from .vehicle import placement as vehicle_placement

__all__ = ["SweepResult", "sweep", "impact_positions_grid", "chunk_width"]

# Runs per device and chunk at most, by platform: throughput no longer rises beyond them.
# CPU: measured (benchmarks/README.md, "Throughput against batch size": 126 runs/s at 64, a
# wider vmap only costs memory); accelerators: thousands of lanes keep a GPU busy.
CHUNK_CAP = {"cpu": 64}
ACCELERATOR_CHUNK_CAP = 8192
CPU_WHEEL_RUNS = 128  # wheels x runs per CPU device and chunk at most (see chunk_width)
MEMORY_FRACTION = 0.5  # of a device's free memory one chunk may take
PERCENTILES = (50.0, 95.0, 99.0)  # % of the Monte Carlo summaries


class SweepResult(NamedTuple):
    """Summary values of a sweep; arrays shaped [n_flats, n_speeds, n_positions].

    Attributes:
        speeds: [n_speeds] train speeds [m/s].
        impact_positions: [n_positions] impact positions within the bay [m].
        max_force, min_force: contact force extremes after the run-in [N].
        loss_of_contact: bool, F = 0 occurred.
        loss_of_contact_duration: time with F = 0 [s].
        max_residual: largest per-step contact-equation residual [m] (solver diagnostic).
        flats: labels of the flats (e.g. ``"rounded d=0.90mm l=100.0mm"``).
        contact: the contact model.
        depths, lengths: [n_flats] flat depth and length [m] (length: l of a rounded flat,
            the chord l0 of a new one, the support of a measured profile).
        sensor_positions: [n_s] sensor positions [m] (``sweep(sensors=...)``), or None.
        sensor_max, sensor_min: [n_flats, n_speeds, n_positions, n_quantities, n_s] extremes
            after the run-in of ``sensor_quantities`` (SI units), or None.
        sensor_quantities: names of the quantity axis (:data:`wfjax.sensors.QUANTITIES`).
        detector_bays: [n_bays] bay indices of the detector (``sweep(detector=...)``), or None.
        detector_peak: [n_flats, n_speeds, n_positions, n_bays] detector reading per bay [N].
        detector_ratio: the same divided by the static wheel load P.
        axle_acc_peak: [n_flats, n_speeds, n_positions] max |axle-box acceleration| of the
            flat's wheel after the run-in [m/s^2].
        wheel_max_force, wheel_min_force: a vehicle's (``sweep(vehicle=...)``) every wheel's
            force extremes, [n_flats, n_speeds, n_positions, n_wheels] [N], or None
            (``max_force`` and ``min_force`` are the flat wheel's).
        wheel_loss_of_contact: the same, bool. wheel_axle_acc_peak: the same [m/s^2].
        wheel_positions: [n_wheels] the wheels' distances behind the leading wheel [m].
        flat_wheel: index of the wheel that carries the swept flats (0 without a vehicle).
    """

    speeds: Any
    impact_positions: Any
    max_force: Any
    min_force: Any
    loss_of_contact: Any
    loss_of_contact_duration: Any
    max_residual: Any
    flats: tuple
    contact: str
    depths: Any = None
    lengths: Any = None
    sensor_positions: Any = None
    sensor_max: Any = None
    sensor_min: Any = None
    detector_bays: Any = None
    detector_peak: Any = None
    detector_ratio: Any = None
    sensor_quantities: tuple = ()
    axle_acc_peak: Any = None
    wheel_max_force: Any = None
    wheel_min_force: Any = None
    wheel_loss_of_contact: Any = None
    wheel_axle_acc_peak: Any = None
    wheel_positions: Any = None
    flat_wheel: int = 0
    realisation_max_force: Any = None
    realisation_min_force: Any = None

    def percentiles(self, q=PERCENTILES) -> np.ndarray:
        """Percentiles ``q`` [%] over the roughness realisations of each realisation's max
        force (its max over the impact positions): [n_flats, n_speeds, len(q)] [N].

        Linear interpolation between order statistics (``numpy.percentile``'s default).
        Needs a sweep over realisations (``sweep(roughness=...)`` with ``values [R, n]``).
        """
        if self.realisation_max_force is None:
            raise ValueError("this sweep has no roughness realisations "
                             "(sweep(..., roughness=Roughness with values [R, n]))")
        worst = np.max(np.asarray(self.realisation_max_force), axis=2)  # [f, v, R]
        return np.moveaxis(np.percentile(worst, np.asarray(q, dtype=float), axis=-1), 0, -1)

    def percentiles_to_csv(self, q=PERCENTILES) -> str:
        """One row per (flat, speed): the percentiles of the max force [kN] over the
        realisations (:meth:`percentiles`), their mean and the realisation count."""
        pct = self.percentiles(q)
        worst = np.max(np.asarray(self.realisation_max_force), axis=2)
        buf = io.StringIO()
        w = csv.writer(buf)
        w.writerow(["flat", "contact", "speed_kmh", "realisations", "mean_max_force_kN"]
                   + [f"p{g:g}_max_force_kN" for g in q])
        for i, label in enumerate(self.flats):
            for j, v in enumerate(np.asarray(self.speeds)):
                w.writerow([label, self.contact, f"{v * 3.6:.6g}", worst.shape[-1],
                            f"{worst[i, j].mean() / 1e3:.6f}"]
                           + [f"{x / 1e3:.6f}" for x in pct[i, j]])
        return buf.getvalue()

    def envelope(self) -> dict[str, np.ndarray]:
        """Max over positions of max_force, min over positions of min_force: [n_flats, n_speeds]."""
        return {
            "max_force": np.max(self.max_force, axis=-1),
            "min_force": np.min(self.min_force, axis=-1),
            "loss_of_contact": np.any(self.loss_of_contact, axis=-1),
        }

    def to_csv(self) -> str:
        """One row per (flat, speed, position); forces in kN, speeds in km/h."""
        buf = io.StringIO()
        w = csv.writer(buf)
        w.writerow(["flat", "contact", "speed_kmh", "impact_position_mm", "max_force_kN",
                    "min_force_kN", "loss_of_contact", "loss_of_contact_ms", "depth_mm",
                    "length_mm"])
        depths = np.full(len(self.flats), np.nan) if self.depths is None else self.depths
        lengths = np.full(len(self.flats), np.nan) if self.lengths is None else self.lengths
        for i, label in enumerate(self.flats):
            for j, v in enumerate(np.asarray(self.speeds)):
                for k, p in enumerate(np.asarray(self.impact_positions)):
                    w.writerow([label, self.contact, f"{v * 3.6:.6g}", f"{p * 1e3:.6g}",
                                f"{self.max_force[i, j, k] / 1e3:.6f}",
                                f"{self.min_force[i, j, k] / 1e3:.6f}",
                                int(self.loss_of_contact[i, j, k]),
                                f"{self.loss_of_contact_duration[i, j, k] * 1e3:.6g}",
                                f"{depths[i] * 1e3:.6g}", f"{lengths[i] * 1e3:.6g}"])
        return buf.getvalue()

    def sensors_to_csv(self) -> str:
        """One row per (flat, speed, position, sensor): max and min of every quantity (SI)."""
        if self.sensor_max is None:
            raise ValueError("this sweep has no sensors (sweep(..., sensors=[...]))")
        buf = io.StringIO()
        w = csv.writer(buf)
        w.writerow(["flat", "speed_kmh", "impact_position_mm", "sensor_m"]
                   + [f"{q}_{e}" for q in self.sensor_quantities for e in ("max", "min")])
        for (i, j, k), _ in np.ndenumerate(self.max_force):
            for m, x in enumerate(np.asarray(self.sensor_positions)):
                vals = [f"{a[i, j, k, n, m]:.9g}" for n in range(len(self.sensor_quantities))
                        for a in (self.sensor_max, self.sensor_min)]
                w.writerow([self.flats[i], f"{self.speeds[j] * 3.6:.6g}",
                            f"{self.impact_positions[k] * 1e3:.6g}", f"{x:.6g}", *vals])
        return buf.getvalue()

    def save_npz(self, path) -> None:
        """Save every array and label to ``path`` (.npz), atomically."""
        path = Path(path)
        tmp = path.with_name(f".{path.name}.tmp.npz")
        arrays = {k: np.asarray(getattr(self, k)) for k in self._fields
                  if k not in ("flats", "contact") and getattr(self, k) is not None}
        np.savez(tmp, flats=np.array(self.flats), contact=np.array(self.contact), **arrays)
        tmp.replace(path)

    @classmethod
    def load_npz(cls, path) -> SweepResult:
        """Load a result written by :meth:`save_npz`."""
        with np.load(path) as data:
            fields = {k: data[k] for k in cls._fields
                      if k not in ("flats", "contact") and k in data}
            if "sensor_quantities" in fields:
                fields["sensor_quantities"] = tuple(str(q) for q in fields["sensor_quantities"])
            return cls(flats=tuple(str(s) for s in data["flats"]),
                       contact=str(data["contact"]), **fields)

    def summary(self) -> dict:
        """JSON-ready summary per flat (kN, km/h)."""
        env = self.envelope()
        out = {"contact": self.contact, "flats": {}}
        for i, label in enumerate(self.flats):
            lost = np.asarray(self.speeds)[env["loss_of_contact"][i]] * 3.6
            j = int(np.argmax(env["max_force"][i]))
            out["flats"][label] = {
                "peak_max_force_kN": float(env["max_force"][i, j]) / 1e3,
                "at_speed_kmh": float(self.speeds[j]) * 3.6,
                "first_loss_of_contact_kmh": float(lost.min()) if lost.size else None,
                "max_spread_over_positions_percent": float(np.max(
                    np.ptp(self.max_force[i], axis=-1) / np.min(self.max_force[i], axis=-1)
                )) * 100,
            }
        if self.wheel_max_force is not None:
            out["flat_wheel"] = int(self.flat_wheel)
            out["wheels"] = self.wheel_summary()
        if self.axle_acc_peak is not None:
            out["peak_axle_acc_m_s2"] = float(np.max(self.axle_acc_peak))
        if self.realisation_max_force is not None:
            pct = self.percentiles()
            out["realisations"] = int(np.shape(self.realisation_max_force)[-1])
            out["max_force_percentiles_kN"] = {
                label: {f"p{g:g}": [float(x) / 1e3 for x in pct[i, :, k]]
                        for k, g in enumerate(PERCENTILES)}
                for i, label in enumerate(self.flats)}
        return out

    def wheel_summary(self) -> list[dict]:
        """Per wheel of a vehicle sweep (over flats, speeds and positions): peak max force,
        lowest min force [kN] and peak axle-box acceleration [m/s^2]; [] without a vehicle."""
        if self.wheel_max_force is None:
            return []
        axes = (0, 1, 2)
        return [{"position_m": float(p),
                 "peak_max_force_kN": float(mx) / 1e3, "lowest_min_force_kN": float(mn) / 1e3,
                 "loss_of_contact": bool(lost), "peak_axle_acc_m_s2": float(acc)}
                for p, mx, mn, lost, acc in zip(
                    self.wheel_positions, np.max(self.wheel_max_force, axis=axes),
                    np.min(self.wheel_min_force, axis=axes),
                    np.any(self.wheel_loss_of_contact, axis=axes),
                    np.max(self.wheel_axle_acc_peak, axis=axes), strict=True)]

    def to_json(self) -> str:
        """:meth:`summary` as JSON text."""
        return json.dumps(self.summary(), indent=2)


def flat_label(flat: Flat) -> str:
    """A short human label of a flat (mm)."""
    d = float(flat.depth) * 1e3
    if flat.kind == "rounded":
        return f"rounded d={d:.2f}mm l={float(flat.length) * 1e3:.1f}mm"
    if flat.kind == "new":
        return f"new d={d:.2f}mm"
    return f"{flat.kind} d={d:.2f}mm"


def _realisation(rough, index):
    """The loop roughness of realisation ``index`` (a rail profile's ``values [R, n]``)."""
    if rough is None:
        return None
    rail = rough.rail
    if rail is not None and jnp.ndim(rail.values) == 2:
        rail = dataclasses.replace(rail, values=rail.values[index])
    wheel = rough.wheel
    if wheel is not None and jnp.ndim(wheel.values) == 2:
        wheel = dataclasses.replace(wheel, values=wheel.values[index])
    return rough._replace(rail=rail, wheel=wheel)


def _reduce(n_steps, max_iter, precision, laws, struct, extras, n_run, flat_index, speed, dt,
            x_start, impact_position, run_in_steps, end_steps, realisation) -> dict:
    """One run's summaries by name (:data:`SUMMARY_KEYS`; per wheel, sensors and the
    detector where the sweep has them)."""
    batched, others = laws
    if extras.get("tracks") is not None:  # support realisations: this run's modal model
        struct = struct._replace(track=_pick_model(extras["tracks"], realisation))
    law = jax.tree.map(lambda a: a[flat_index], batched)
    if others is not None:  # a vehicle: the swept flat's law on its wheel, the others fixed
        law = tuple(law if o is None else o for o in others)
    observers = tuple(o for o in (
        None if extras["sensors"] is None else Sensors(extras["sensors"], run_in_steps,
                                                       end_steps, history=False),
        None if extras["detector"] is None else DetectorReadings(extras["detector"], end_steps,
                                                                 history=False)) if o is not None)
    hist = run_scan(law, struct, speed, dt, x_start, impact_position, n_steps, max_iter,
                    observers=observers, precision=precision,
                    roughness=_realisation(extras.get("roughness"), realisation), n_run=n_run)
    contact = {k: hist[k] for k in ("t",) + StepOutput._fields}
    out = {}
    if others is None:
        res = summarise(contact, speed, impact_position, dt, run_in_steps, end_steps=end_steps)
    else:
        flat_wheel = [o is None for o in others].index(True)
        res = summarise_vehicle(contact, flat_wheel, speed, impact_position, dt, run_in_steps,
                                end_steps=end_steps)
        out = {"w_max": res.wheel_max_force, "w_min": res.wheel_min_force,
               "w_lost": res.wheel_loss_of_contact, "w_acc": res.wheel_axle_acc_peak}
    out |= {"max": res.max_force, "min": res.min_force, "lost": res.loss_of_contact,
            "lost_t": res.loss_of_contact_duration, "res": jnp.max(res.residual),
            "acc": res.axle_acc_peak}
    names = {"sensor_max": "s_max", "sensor_min": "s_min", "detector_peak": "det"}
    return out | {short: hist[k] for k, short in names.items() if k in hist}


@functools.cache
def _batched(mesh: Mesh, n_steps: int, max_iter: int, precision: str = "float64"):
    """Compiled (laws, struct, extras, flat_index, speed, dt, x_start, impact_position,
    run_in, end, realisation) -> summaries, for laws stacked along a leading flat axis (one
    program per law class).

    ``shard_map`` gives every device its own ``vmap``-ed loop over its runs: the batched
    Newton ``while_loop`` then stops on the device's own runs, with no cross-device reduction
    of its condition at every step (what a plain ``jit`` over sharded inputs would compile).
    Every device's loop stops at its own runs' longest window (``time_loop(n_run=...)``).
    """
    def local(laws, struct, extras, *runs):
        n_run = jnp.max(runs[_END_STEPS])  # the longest own window among this device's runs
        return jax.vmap(functools.partial(_reduce, n_steps, max_iter, precision, laws, struct,
                                          extras, n_run))(*runs)

    by_run = PartitionSpec("runs")
    return jax.jit(jax.shard_map(local, mesh=mesh, out_specs=by_run, check_vma=False,
                                 in_specs=(PartitionSpec(),) * 3 + (by_run,) * 8),
                   compiler_options=LOOP_COMPILER_OPTIONS)


def _device_mesh() -> Mesh:
    """A one-axis mesh ``("runs",)`` over every JAX device (all hosts)."""
    return Mesh(np.array(jax.devices()), ("runs",))


def _shard_runs(a: np.ndarray, mesh: Mesh) -> jax.Array:
    """Global array of the [n] per-run values ``a``, split along ``"runs"`` (n % devices == 0).

    Every process holds the same ``a`` and contributes the shards of its own devices.
    """
    sharding = NamedSharding(mesh, PartitionSpec("runs"))
    return jax.make_array_from_callback(a.shape, sharding, lambda idx: a[idx])


def _replicate(tree, mesh: Mesh):
    """Array leaves of ``tree`` replicated on every device of ``mesh`` (other leaves unchanged)."""
    sharding = NamedSharding(mesh, PartitionSpec())

    def put(x):
        if not isinstance(x, (jax.Array, np.ndarray)):
            return x
        host = np.asarray(x)
        return jax.make_array_from_callback(host.shape, sharding, lambda idx: host[idx])

    return jax.tree.map(put, tree)


def _gather(arrays) -> list[np.ndarray]:
    """Sharded results as host NumPy arrays (an all-gather across processes on multi-host)."""
    if jax.process_count() > 1:
        return [np.asarray(a) for a in multihost_utils.process_allgather(arrays, tiled=True)]
    return [np.asarray(a) for a in arrays]


class _Progress:
    """Runs done of ``total`` with an ETA; ``work`` (e.g. run-steps) done and in all, when
    given, paces the ETA (a sweep's chunks of short runs go first)."""

    def __init__(self, total: int, label: str, stream=sys.stderr, enabled: bool = True):
        self.total, self.label, self.stream, self.enabled = total, label, stream, enabled
        self.start = time.perf_counter()
        self.done = 0
        self.work_done, self.work_total = 0.0, None

    def update(self, n: int, work: float | None = None) -> None:
        self.done += n
        self.work_done += n if work is None else work
        if not self.enabled:
            return
        elapsed = time.perf_counter() - self.start
        total = self.total if self.work_total is None else self.work_total
        eta = (elapsed / self.work_done * (total - self.work_done) if self.work_done
               else float("nan"))
        end = "\n" if self.done >= self.total else "\r"
        line = (f"  {self.label}: {self.done}/{self.total} runs, {elapsed:5.1f} s elapsed, "
                f"ETA {eta:5.1f} s")
        print(line.ljust(len(self.label) + 40), end=end, file=self.stream, flush=True)


def sweep(flats: Flat | Sequence[Flat], speeds, impact_positions=10, contact: str = "3d",
          wheel: Wheel | None = None, track: Track | None = None,
          material: Material | None = None, config: SimConfig | None = None,
          chunk_size: int | None = None, progress: bool = True, cache_dir=None, sensors=None,
          detector=None, sensor_quantities=QUANTITIES, vehicle=None, roughness=None,
          wheel_roughness=None, tracks=None) -> SweepResult:
    """Max/min contact force for every flat x speed x impact position.

    Args:
        flats: one :class:`Flat` or a sequence of them, run in groups that each compile
            once (:func:`batch_groups`): a kind's flats batched through a traced law share
            the window of the largest; flats with exact 3D tables keep their own windows.
            Every run takes :func:`wfjax.simulate`'s step count and time step at its speed.
        speeds: [n_speeds] train speeds [m/s].
        impact_positions: number of positions evenly covering one bay
            (:func:`impact_positions_grid`) or an array of positions [m] in [0, L_S).
        contact: ``"3d"``, ``"2d"``, ``"hertz-trajectory"`` or ``"hertz-profile"``.
        wheel, track, material, config: model parameters (defaults as in :func:`simulate`).
        chunk_size: simulations per vmapped batch over all devices (default: per device
            :func:`chunk_width`, from its memory); each chunk is padded to a multiple of the
            device count and sharded across the devices.
        progress: print progress with ETA to stderr.
        sensors: [n_s] fixed rail positions [m] (as :func:`wfjax.simulate`): the max and min
            of each of ``sensor_quantities`` (default every one of
            :data:`wfjax.sensors.QUANTITIES`) at each, per run.
        detector: a :class:`wfjax.sensors.Detector`: its reading per bay, per run (the runs'
            windows are lengthened so that the wheel crosses every bay).
        vehicle: a :class:`wfjax.vehicle.Vehicle` (as :func:`wfjax.simulate`): every flat is
            swept on ``vehicle.flat_wheel``, the other wheels roll with it on the same track;
            per-wheel extremes in the ``wheel_*`` fields (a detector's peak per wheel and bay).
        roughness: rail roughness (:class:`wfjax.roughness.Roughness`, as
            :func:`wfjax.simulate`). Monte Carlo: ``values [R, n]`` are R realisations, a
            batch axis of the runs (one compile, chunked like the runs): every flat x speed
            x position runs on every realisation.
        wheel_roughness: wheel roughness (periodic), ``values [n]`` or ``[R, n]`` (the same
            R as ``roughness``'s when both are batched).
        tracks: support realisations, a sequence of R :class:`Track` (e.g.
            ``[supports.scatter(track, key=k) for k in range(R)]``; replaces ``track``): one
            modal model each (cached), padded to a common mode count (zero-weight modes) so
            one compile serves them; realisation r runs on ``tracks[r]`` (and on roughness
            realisation r when the roughness is batched too: the same R). Not with a
            vehicle, sensors or a detector.

    Returns:
        :class:`SweepResult` with arrays shaped [n_flats, n_speeds, n_positions]: with
        roughness realisations, the extremes over them (max of ``max_force``, min of
        ``min_force``, any loss of contact), and every realisation's in
        ``realisation_max_force`` / ``realisation_min_force`` [n_flats, n_speeds,
        n_positions, R]; :meth:`SweepResult.percentiles` summarises them.
    """
    wheel = wheel or Wheel()
    track = track or Track()
    material = material or Material()
    config = config or SimConfig()
    flat_list = [flats] if isinstance(flats, Flat) else list(flats)
    if not flat_list:
        raise ValueError("flats must contain at least one Flat")
    v = check_speeds(speeds)
    spacing = float(track.sleeper_spacing)
    if np.ndim(impact_positions) == 0:
        pos = impact_positions_grid(impact_positions, spacing)
    else:
        pos = check_impact_positions(impact_positions, track)
    if chunk_size is not None and (int(chunk_size) != chunk_size or chunk_size < 1):
        raise ValueError(f"chunk_size must be an integer >= 1 or None, got {chunk_size!r}")
    registry.check(contact)
    if detector is not None:
        config = detector_config(detector, track, config,
                                 wheel_positions(vehicle, float(track.sleeper_spacing)))
    models = None
    if tracks is not None:
        tracks = list(tracks)
        if not tracks or vehicle is not None or sensors is not None or detector is not None:
            raise ValueError("tracks (support realisations) must be a non-empty sequence of "
                             "Track, and cannot be combined with a vehicle, sensors or a "
                             "detector")
        if any(supports_mod.hanging_sleepers(tr).size for tr in tracks):
            raise ValueError("tracks (support realisations) must not have hanging sleepers "
                             "(ballast_gap > 0): sweep one such track at a time")
        track = tracks[0]
        models = padded_models(tracks, config, cache_dir)
    mesh = _device_mesh()
    groups = batch_groups(flat_list, contact, config)
    if progress and any(g.tables for g in groups):
        print("  building the 3D contact tables (cached after the first run) ...", end="\r",
              file=sys.stderr, flush=True)
    # the exact 3D tables are built while the modal model builds and the program compiles
    tables_ahead = {tuple(g.indices): in_background(
        cached_tables_3d, [flat_list[i] for i in g.indices], float(wheel.radius),
        float(track.rail_head_radius), material, config.contact_element, cache_dir)
        for g in groups if g.tables}
    fleet = _Fleet.of(vehicle, wheel, flat_list, contact, track, material, config, v,
                      cache_dir)
    struct_host = fleet.struct if vehicle is not None else structure(wheel, track, config,
                                                                      cache_dir)
    if models is not None:
        struct_host = struct_host._replace(track=_pick_model(models, 0))
    struct = _replicate(struct_host, mesh)
    rough, n_real = _sweep_roughness(roughness, wheel_roughness, vehicle, wheel, track,
                                     material)
    if models is not None:
        if rough is not None and n_real > 1 and n_real != len(tracks):
            raise ValueError(f"roughness realisations ({n_real}) and support realisations "
                             f"(tracks: {len(tracks)}) must be as many when both are given")
        n_real = len(tracks)
    extras = _replicate(_sensor_extras(sensors, sensor_quantities, detector, track,
                                       struct_host.track)
                        | {"roughness": rough, "tracks": models}, mesh)
    others = None if vehicle is None else _replicate(fleet.others, mesh)
    out = {}
    for group, exact_tables in groups:
        members = [flat_list[i] for i in group]
        label = (flat_label(members[0]) if len(members) == 1
                 else f"{len(members)} flats" if exact_tables
                 else f"{len(members)} {members[0].kind} flats")
        if progress:  # a 3D table or family build takes seconds to a minute on a cold cache
            what = "3D contact tables" if exact_tables else f"{contact} contact law"
            print(f"  {label}: preparing the {what} ...", end="\r", file=sys.stderr,
                  flush=True)
        program = None
        if exact_tables:  # compile for the tables' shapes while they are being built
            laws, window_flats = _table_laws_like(members, wheel, track, material, config), members
        else:
            laws, window_flats = prepare_batch(contact, members, wheel, track, material, config,
                                               cache_dir, progress)
        if vehicle is not None:
            window_flats = [fleet.window_flat(w) for w in window_flats]
        if roughness is not None:
            s0 = min(simulation_window(w, float(speed), config)[0]
                     for w in window_flats for speed in v)
            s1 = max(simulation_window(w, float(speed), config)[1]
                     for w in window_flats for speed in v)
            offs = np.zeros(1) if vehicle is None else vehicle.offsets()
            check_rail_span(roughness, float(pos.min() + fleet.shift + s0 + offs.min()),
                            float(pos.max() + fleet.shift + s1 + offs.max()))
        runs = _plan_runs(window_flats, v, pos + fleet.shift, struct, config, mesh, chunk_size,
                          n_real)
        if exact_tables:
            program = _compile_runs((_replicate(laws, mesh), others), struct, extras, runs,
                                    config, mesh)
            like = laws
            laws = _table_laws(tables_ahead[tuple(group)].result())
            if jax.tree.map(np.shape, laws) != jax.tree.map(np.shape, like):
                program = None  # not the shapes it was compiled for: compile as usual
        cols = _run_group((_replicate(laws, mesh), others), struct, extras, runs, config, mesh,
                          _Progress(len(members) * v.size * pos.size * n_real, label,
                                    enabled=progress), program)
        for key, col in cols.items():
            batch = rough is not None or models is not None
            if batch and key in ("max", "min"):
                out.setdefault("r_" + key, np.zeros((len(flat_list),) + col.shape[1:]))[
                    group] = col
            col = _over_realisations(key, col) if batch else col[:, :, :, 0]
            out.setdefault(key, np.zeros((len(flat_list),) + col.shape[1:]))[group] = col
    det = {"axle_acc_peak": out["acc"]}
    if rough is not None or models is not None:
        det |= {"realisation_max_force": out["r_max"], "realisation_min_force": out["r_min"]}
    if detector is not None:
        loads = fleet.preloads[:, None] if vehicle is not None else float(wheel.preload)
        det |= {"detector_bays": detector.bays(), "detector_peak": out["det"],
                "detector_ratio": out["det"] / loads}
    if vehicle is not None:
        det |= {"wheel_max_force": out["w_max"], "wheel_min_force": out["w_min"],
                "wheel_loss_of_contact": out["w_lost"].astype(bool),
                "wheel_axle_acc_peak": out["w_acc"],
                "wheel_positions": np.asarray(vehicle.positions),
                "flat_wheel": int(vehicle.flat_wheel)}
    if sensors is not None:
        det |= {"sensor_positions": np.asarray(extras["sensors"].positions),
                "sensor_max": out["s_max"], "sensor_min": out["s_min"],
                "sensor_quantities": extras["sensors"].quantities}
    return SweepResult(
        speeds=v, impact_positions=pos, max_force=out["max"], min_force=out["min"],
        loss_of_contact=out["lost"].astype(bool), loss_of_contact_duration=out["lost_t"],
        max_residual=out["res"], flats=tuple(flat_label(f) for f in flat_list), contact=contact,
        depths=np.array([float(np.asarray(f.depth)) for f in flat_list]),
        lengths=np.array([float(np.asarray(f.length)) for f in flat_list]), **det,
    )


@dataclasses.dataclass
class _Fleet:
    """A sweep's vehicle: the structure, the fixed wheels' laws and the placement."""

    vehicle: Any = None
    struct: Any = None
    others: tuple | None = None  # [n] laws, None at the flat wheel
    flats: list | None = None
    shift: float = 0.0  # rail coordinate of the reference wheel's impact bay [m]
    preloads: Any = None
    track: Any = None
    speeds: Any = None
    config: Any = None

    @classmethod
    def of(cls, vehicle, wheel, flat_list, contact, track, material, config, speeds,
           cache_dir) -> _Fleet:
        if vehicle is None:
            return cls()
        wheels = vehicle.wheel_list(wheel)
        vehicle.check_spacing(wheels)
        for f in flat_list:
            w = wheels[vehicle.flat_wheel]
            if abs(float(f.wheel_radius) - float(w.radius)) > 1e-12:
                raise ValueError(f"flat.wheel_radius ({float(f.wheel_radius)} m) must equal the "
                                 f"flat wheel's radius ({float(w.radius)} m)")
        flats = vehicle.flat_list(Flat.none(float(wheels[vehicle.flat_wheel].radius)),
                                  lambda i: float(wheels[i].radius))
        laws = vehicle_laws(contact, flats, wheels, track, material, config, cache_dir)
        others = tuple(None if i == vehicle.flat_wheel else law for i, law in enumerate(laws))
        return cls(vehicle, vehicle_structure(vehicle, wheels, track, config, cache_dir),
                   others, flats, vehicle_placement(vehicle, float(track.sleeper_spacing)),
                   np.array([float(w.preload) for w in wheels]), track, speeds, config)

    def window_flat(self, swept: Flat) -> Flat:
        """The window of a group whose flats are sized by ``swept``, checked on the track."""
        flats = list(self.flats)
        flats[self.vehicle.flat_wheel] = swept
        window = vehicle_window_flat(self.vehicle, flats)
        spacing = float(self.track.sleeper_spacing)
        for speed in (float(np.min(self.speeds)), float(np.max(self.speeds))):
            s0, s1 = simulation_window(window, speed, self.config)
            check_on_track(self.vehicle, self.track, self.shift + s0, self.shift + s1 + spacing)
        return window


def _sensor_extras(sensors, quantities, detector, track: Track, model) -> dict:
    """The compiled program's sensor and detector specs (None where not asked for)."""
    return {"sensors": (None if sensors is None
                        else sensor_spec(sensors, track, model, quantities)),
            "detector": None if detector is None else detector_spec(detector, track, model)}


class BatchGroup(NamedTuple):
    """Flats of a sweep that share one compiled program.

    Attributes:
        indices: the flats' indices in the sweep's list.
        tables: the flats' exact 3D tables, widened to one shape (:func:`_table_laws`).
    """

    indices: list[int]
    tables: bool = False


def batch_groups(flats: Sequence[Flat], contact: str, config: SimConfig) -> list[BatchGroup]:
    """The flats' groups, each one compiled program.

    Laws whose geometry is a traced leaf (Hertz, 2D bedding, the parametric 3D family) batch
    every new or rounded flat of one kind. The exact 3D tables (``contact_mode_3d="table"``,
    measured profiles and smooth wheels with 3D contact, and under ``"auto"`` a kind with one
    geometry) batch all together, whatever their kinds: their tables are widened to one shape.
    The direct 3D mode, and measured profiles and smooth wheels with the other models, run
    one flat per program.
    """
    mode = config.contact_mode_3d if contact == "3d" else None
    kinds: dict[str, list[int]] = {}
    tables, singles = [], []
    for i, flat in enumerate(flats):
        if mode == "direct":
            singles.append(i)
        elif flat.kind in ("new", "rounded") and mode != "table":
            kinds.setdefault(flat.kind, []).append(i)
        elif contact == "3d":
            tables.append(i)
        else:
            singles.append(i)
    if mode == "auto":  # a kind with one geometry uses its exact table
        for kind in [k for k, members in kinds.items() if len(members) == 1]:
            tables += kinds.pop(kind)
    return ([BatchGroup(members) for members in kinds.values()]
            + ([BatchGroup(sorted(tables), tables=True)] if tables else [])
            + [BatchGroup([i]) for i in singles])


def common_extent(flats: Sequence[Flat]) -> list[Flat]:
    """``flats`` with the largest half extent as ``extent_bound``: the same simulation windows
    for every flat, as :func:`prepare_batch` gives a batch (geometry unchanged)."""
    bound = max(f.half_extent for f in flats)
    return [dataclasses.replace(f, extent_bound=bound) for f in flats]


def prepare_batch(contact: str, flats: Sequence[Flat], wheel: Wheel, track: Track,
                  material: Material, config: SimConfig, cache_dir=None,
                  progress: bool = False):
    """Contact laws of ``flats`` (one kind, or one flat) stacked along a leading flat axis.

    The concrete work (node sets, trajectory grids, the 3D family) is done once for the whole
    batch; the geometry enters through ``jax.vmap`` over the stacked flats, so the laws'
    geometry leaves are traced and one compiled program serves every flat. Windows are sized
    by the largest flat of the batch (``extent_bound``). (A group of exact 3D tables is
    stacked by :func:`_table_laws`.)

    Returns:
        (laws with leaves [n_flats, ...], [n_flats] the flats that size each one's
        simulation windows).
    """
    sized = common_extent(flats)
    family = None
    if contact == "3d":
        if resolve_mode_3d(config, batched=len(flats) > 1) != "parametric":
            (flat,) = flats  # the direct mode: batch_groups gives one flat per group
            law = prepare(contact, flat, wheel, track, material, config, cache_dir)
            return _stack([law]), [flat]
        family = prepare_family(flats, wheel, track, material, config, cache_dir, progress)
    max_depth = max(float(np.max(np.asarray(f.depth))) for f in flats)
    stacked = _stack(sized)

    def prepare_one(flat, family):
        return prepare(contact, flat, wheel, track, material, config, cache_dir, family=family,
                       max_depth=max_depth)

    # Compiled (and, from the command line, cached on disk) rather than run op by op: the
    # parametric law reads the family at a few hundred positions per flat (7.6 s eagerly for
    # the Fig. 8 set).
    laws = jax.jit(jax.vmap(prepare_one, in_axes=(0, None)))(stacked, family)
    return laws, [sized[0]] * len(flats)


class _Runs(NamedTuple):
    """A group's runs, flattened over (flat, speed, position, realisation), and their chunks.

    ``columns``: [n] per-run arrays in the order of the program's run arguments (flat index,
    speed [m/s], dt [s], x_start [m], impact position [m], run-in steps, end step,
    realisation), the runs sorted by their step count (``order``: where each one's results
    go); ``step`` runs per chunk, each padded to ``width`` (a multiple of the device count);
    ``shape`` (n_flats, n_speeds, n_positions, n_real).
    """

    n_steps: int
    columns: tuple
    step: int
    width: int
    shape: tuple
    order: np.ndarray  # [n] each planned run's index in the (flat, speed, position,
    # realisation) order of the results

    def chunk_runs(self, lo: int) -> int:
        """Runs in the chunk starting at run ``lo`` (before padding)."""
        return min(self.step, self.columns[0].size - lo)


_END_STEPS = 6  # the end-step column among _Runs.columns (_reduce's run arguments)


def _plan_runs(window_flats: Sequence[Flat], v, pos, struct, config: SimConfig, mesh: Mesh,
               chunk_size: int | None, n_real: int = 1) -> _Runs:
    """The runs of one group: flat i runs at every speed in the window of ``window_flats[i]``
    there, with the step count and time step :func:`wfjax.simulate` takes
    (:func:`run_windows`); the program's step count is the largest, and the steps after a
    run's own window are not counted in its summaries. The runs are sorted by their step
    count, so a chunk's loop stops at its longest run (on each device: the runs are dealt to
    the devices in turn); chunks: ``chunk_size`` runs, default from the devices' memory
    (:func:`chunk_width`)."""
    n_flats = len(window_flats)
    windows = [run_windows(f, v, config) for f in window_flats]
    n_fv, dt_fv, s0_fv, run_in_fv = (np.stack([w[i] for w in windows]) for i in range(4))
    n_steps = int(n_fv.max())
    if chunk_size is None:
        n_modes = int(struct.track.poles.shape[0])
        n_wheels = 1 if struct.offsets is None else int(struct.offsets.shape[0])
        per_device = chunk_width(n_steps, n_modes, config.precision, n_wheels=n_wheels)
        if jax.process_count() > 1:  # every process must compile and run the same chunks
            per_device = int(np.min(multihost_utils.process_allgather(np.int32(per_device))))
        chunk_size = mesh.devices.size * per_device
    ff, jj, kk, rr = (a.ravel() for a in np.meshgrid(np.arange(n_flats), np.arange(v.size),
                                                     np.arange(pos.size), np.arange(n_real),
                                                     indexing="ij"))
    pp, s_start = pos[kk], s0_fv[ff, jj]
    columns = (ff, v[jj], dt_fv[ff, jj], pp + s_start, pp, run_in_fv[ff, jj], n_fv[ff, jj], rr)
    step, width = _chunk_layout(ff.size, chunk_size, mesh.devices.size)
    order = _dealt(np.argsort(n_fv[ff, jj], kind="stable"), step, mesh.devices.size)
    return _Runs(n_steps, tuple(a[order] for a in columns), step, width,
                 (n_flats, v.size, pos.size, n_real), order)


def _dealt(order: np.ndarray, step: int, n_devices: int) -> np.ndarray:
    """``order`` with every chunk of ``step`` runs dealt to the devices in turn (device d
    gets the chunk's runs d, d + n_devices, ...), so each device's share of a sorted chunk
    spans its range of step counts, not one end of it."""
    return np.concatenate([np.concatenate([chunk[d::n_devices] for d in range(n_devices)])
                           for chunk in np.split(order, range(step, order.size, step))])


def _chunk(runs: _Runs, lo: int, mesh: Mesh) -> tuple[int, list]:
    """(runs in the chunk starting at run ``lo``, its sharded arguments, padded to width)."""
    n = runs.chunk_runs(lo)
    pad = runs.width - n
    return n, [_shard_runs(np.concatenate([a[lo:lo + n], np.repeat(a[lo + n - 1:lo + n], pad)]),
                           mesh) for a in runs.columns]


def _program(runs: _Runs, config: SimConfig, mesh: Mesh):
    return _batched(mesh, runs.n_steps, config.newton_iterations, config.precision)


def _compile_runs(laws, struct, extras, runs: _Runs, config: SimConfig, mesh: Mesh):
    """The group's program compiled ahead of time for laws shaped like ``laws`` (their values
    unused), so that it compiles while the laws are still being built."""
    return _program(runs, config, mesh).lower(laws, struct, extras,
                                              *_chunk(runs, 0, mesh)[1]).compile()


def _stack(trees):
    """Pytrees of equal structure and shapes stacked along a new leading (flat) axis."""
    return jax.tree.map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *trees)


def _table_laws(tables) -> TableLaw:
    """The laws of a group's exact 3D tables ([n_flats] :class:`ContactTable`), each widened
    to the most columns among them (:func:`wfjax.contact.tables.pad_columns`), stacked."""
    n_s = max(int(t.onset.shape[0]) for t in tables)
    return jax.tree.map(lambda *xs: to_device(np.stack([np.asarray(x) for x in xs])),
                        *[TableLaw(pad_columns(t, n_s)) for t in tables])


def _table_laws_like(flats: Sequence[Flat], wheel: Wheel, track: Track, material: Material,
                     config: SimConfig):
    """Zeros shaped as :func:`_table_laws` of the flats' tables (for compiling ahead: the
    tables' layouts, :func:`wfjax.contact.table_law.table_specs_3d`, are known before they are
    built)."""
    specs = table_specs_3d(flats, float(wheel.radius), float(track.rail_head_radius), material,
                           config.contact_element)
    n, n_s, n_t = len(flats), max(sp.n_s for sp in specs), specs[0].n_t
    scalar = np.zeros(n)
    return TableLaw(ContactTable(s_min=scalar, ds=scalar, c_max=scalar,
                                 onset=np.zeros((n, n_s)), force=np.zeros((n, n_s, n_t)),
                                 slope=np.zeros((n, n_s, n_t)), converged=scalar))


def _run_group(laws, struct, extras, runs: _Runs, config: SimConfig, mesh: Mesh,
               bar: _Progress, program=None) -> dict[str, np.ndarray]:
    """Summaries by name, [n_flats, n_speeds, n_positions, n_real, ...], of one batch of
    laws, chunked and
    sharded (the realisation axis: roughness or support realisations, 1 without), by
    ``program`` (:func:`_compile_runs`; default the jitted :func:`_batched`).

    Every chunk is dispatched before the previous one is collected (one chunk in flight)."""
    program = program or _program(runs, config, mesh)
    results, in_flight = [], None
    starts = range(0, runs.columns[0].size, runs.step)
    ends = runs.columns[_END_STEPS]  # a chunk's work: its runs x its longest run's steps
    work = [runs.chunk_runs(lo) * int(ends[lo:lo + runs.step].max()) for lo in starts]
    bar.work_total = float(sum(work))

    def collect(batch, n, chunk_work):
        keys = sorted(batch)
        results.append(dict(zip(keys, (b[:n] for b in _gather([batch[k] for k in keys])),
                                strict=True)))
        bar.update(n, chunk_work)

    for lo, chunk_work in zip(starts, work, strict=True):
        n, args = _chunk(runs, lo, mesh)
        batch = program(laws, struct, extras, *args)
        if in_flight is not None:
            collect(*in_flight)
        in_flight = (batch, n, chunk_work)
    collect(*in_flight)
    return {k: _unsorted(np.concatenate([r[k] for r in results]), runs.order).reshape(
        runs.shape + results[0][k].shape[1:]) for k in results[0]}


def _unsorted(planned: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Per-run results [n, ...] in planned order back in the results' order."""
    out = np.empty_like(planned)
    out[order] = planned
    return out


_MIN_KEYS = ("min", "w_min", "s_min")


def _over_realisations(key: str, col: np.ndarray) -> np.ndarray:
    """A per-run summary [n_flats, n_speeds, n_positions, R, ...] reduced over the
    realisations: min for minima, max for the rest (maxima, peaks, loss-of-contact flags and
    durations, residuals)."""
    return np.min(col, axis=3) if key in _MIN_KEYS else np.max(col, axis=3)


def _sweep_roughness(rail, wheel, vehicle, wheel_model, track, material):
    """(the loop roughness with its realisations, R) of a sweep (None, 1 without)."""
    if rail is None and wheel is None:
        return None, 1
    counts = {int(np.shape(r.values)[0]) for r in (rail, wheel)
              if r is not None and np.ndim(r.values) == 2}
    if len(counts) > 1:
        raise ValueError(f"roughness and wheel_roughness must hold the same number of "
                         f"realisations, got {sorted(counts)}")
    wheels = None if vehicle is None else vehicle.wheel_list(wheel_model or Wheel())
    rough = loop_roughness(rail, wheel, wheels or [wheel_model or Wheel()], track, material)
    return rough, counts.pop() if counts else 1


def padded_models(tracks, config: SimConfig, cache_dir=None):
    """The modal models of support realisations ``tracks`` [R] stacked along a leading axis,
    every one padded to the largest mode count with zero-weight, zero-shape modes (pole -1
    rad/s: they carry no load and add nothing), so one compiled program serves them.

    The rails must share their mesh and residual table layout (same ``n_bays``,
    ``elements_per_bay``, ``sleeper_spacing``; all uniform or all varying supports).

    Returns:
        :class:`wfjax.track.ModalModel` with array fields [R, ...] (``sleeper_spacing`` and
        ``element_phi`` shared).
    """
    from . import track as track_mod

    models = [track_mod.modal_model(tr, max_frequency=config.track_max_frequency,
                                    cache_dir=cache_dir) for tr in tracks]
    first = models[0]
    for i, m in enumerate(models):
        if (m.node_x.shape != first.node_x.shape or m.residual_x.shape != first.residual_x.shape
                or float(m.sleeper_spacing) != float(first.sleeper_spacing)
                or not np.allclose(np.asarray(m.residual_x), np.asarray(first.residual_x))):
            raise ValueError(f"tracks[{i}]: support realisations must share the rail mesh and "
                             f"residual table of tracks[0] (n_bays, elements_per_bay, "
                             f"sleeper_spacing; all uniform or all varying supports)")
    n = max(int(m.poles.shape[0]) for m in models)

    def pad(a, fill):
        a = np.asarray(a)
        extra = np.full((n - a.shape[0],) + a.shape[1:], fill, dtype=a.dtype)
        return np.concatenate([a, extra])

    def stack(name, fill):
        return to_device(np.stack([pad(getattr(m, name), fill) for m in models]))

    sleeper = (None if first.sleeper_shapes is None else stack("sleeper_shapes", 0.0))
    return first._replace(
        poles=stack("poles", -1.0 + 0j), weights=stack("weights", 0.0),
        shapes=stack("shapes", 0.0), sleeper_shapes=sleeper,
        node_x=to_device(np.stack([np.asarray(m.node_x) for m in models])),
        residual_x=to_device(np.stack([np.asarray(m.residual_x) for m in models])),
        residual=to_device(np.stack([np.asarray(m.residual) for m in models])))


_MODEL_BATCHED = ("poles", "weights", "shapes", "sleeper_shapes", "node_x", "residual_x",
                  "residual")


def _pick_model(models, index):
    """Realisation ``index`` of :func:`padded_models`' stack."""
    return models._replace(**{k: getattr(models, k)[index] for k in _MODEL_BATCHED
                              if getattr(models, k) is not None})


def bytes_per_run(n_steps: int, n_modes: int, precision: str = "float64",
                  n_wheels: int = 1) -> int:
    """Device memory [bytes] one run of the batched time loop needs (an upper estimate).

    24 complex vectors of ``n_modes`` (carry, propagated state, shapes at the contact and
    their products) and 2 reals per step. Fitted to the compiled program's
    ``memory_analysis()`` on CPU (temporaries at 16 and 64 runs, 599 modes): float64
    215 / 262 KB per run at 1000 / 4000 steps (estimate 246 / 294 KB), float32 74 / 77 KB
    (estimate 123 / 147 KB); the width-independent rest (~11 MB: the structure's modes) is
    left to ``MEMORY_FRACTION``. Every further wheel of a vehicle adds its shapes, their
    products and the gathered nodal rows (8 complex vectors) and its outputs per step.
    """
    real = 8 if precision == "float64" else 4
    return real * (2 * n_steps * n_wheels + (24 + 8 * (n_wheels - 1)) * 2 * n_modes)


def chunk_width(n_steps: int, n_modes: int, precision: str = "float64",
                device: jax.Device | None = None, n_wheels: int = 1) -> int:
    """Runs per device and chunk: as many as ``MEMORY_FRACTION`` of the device's free memory
    holds (:func:`bytes_per_run`), at most the platform's throughput cap (``CHUNK_CAP``: 64
    on CPU; ``ACCELERATOR_CHUNK_CAP`` on GPUs/TPUs) and at least 1. On a CPU the cap counts
    wheel-runs (``CPU_WHEEL_RUNS`` = 128 per device): a step's working set (every wheel's
    nodal mode-shape rows) grows with the wheels, and beyond the caches a wider batch is
    slower per run (measured: 8 wheels 5.98x the one-wheel time per run at 16 runs, 6.4x at 8,
    10.7x at 64).

    ``device``: default the first local device. Free memory: ``device.memory_stats()``
    (``bytes_limit - bytes_in_use``) where the backend
    reports it (GPU, TPU); else the host's available memory over its local device count
    (CPU devices share the host's memory).
    """
    device = device or jax.local_devices()[0]  # this process's (another host's: no stats)
    stats = device.memory_stats() or {}
    if "bytes_limit" in stats:
        free = stats["bytes_limit"] - stats.get("bytes_in_use", 0)
    else:
        free = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES") / max(
            1, jax.local_device_count())
    cap = CHUNK_CAP.get(device.platform, ACCELERATOR_CHUNK_CAP)
    if device.platform == "cpu":
        cap = min(cap, max(1, CPU_WHEEL_RUNS // n_wheels))
    fits = int(MEMORY_FRACTION * free // bytes_per_run(n_steps, n_modes, precision, n_wheels))
    return max(1, min(cap, fits))


def _chunk_layout(n_runs: int, chunk_size: int, n_devices: int) -> tuple[int, int]:
    """(runs per chunk, compiled chunk width) for ``n_runs`` runs.

    One compiled shape serves every chunk, so the last chunk is padded to the width; the runs
    are spread evenly over the fewest chunks of at most ``chunk_size`` (80 runs at 64 become
    2 x 40, not 64 + 16 padded to 64), and the width is a multiple of the device count.
    """
    n_chunks = -(-n_runs // chunk_size)
    step = -(-n_runs // n_chunks)
    return step, -(-step // n_devices) * n_devices


def loss_of_contact_speed(result: SweepResult, flat_index: int = 0) -> float:
    """Lowest speed [m/s] of the sweep with loss of contact at any position (nan if none)."""
    lost = np.any(result.loss_of_contact[flat_index], axis=-1)
    return float(np.asarray(result.speeds)[lost].min()) if lost.any() else math.nan

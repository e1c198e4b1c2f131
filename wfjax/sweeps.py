"""Batched simulations, :func:`sweep`: every flat x speed x impact position (x roughness or
support realisation), and their :class:`SweepResult`.

A thin layer over the program core: the arguments become a
:class:`wfjax.scenario.description.Scenario` (checked there), compiled into a
:class:`wfjax.program.core.Program` whose :meth:`~wfjax.program.core.Program.sweep` runs every
run with :func:`wfjax.simulate`'s window and time step, saving its extremes
(:class:`wfjax.program.core.Extremes`). How the runs are grouped, chunked and sharded over the
devices: :mod:`wfjax.program.laws` and :mod:`wfjax.program.grid`.
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from . import labelled
from .params import Flat, Material, SimConfig, Track, Wheel
from .program.core import compile_scenario, tables_ahead
from .program.grid import over_realisations
from .results import flat_label
from .scenario.description import Scenario
from .scenario.sensors import QUANTITIES
from .scenario.windows import impact_positions_grid

__all__ = ["SweepResult", "sweep", "impact_positions_grid", "loss_of_contact_speed"]

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
        sensor_quantities: names of the quantity axis (:data:`wfjax.scenario.sensors.QUANTITIES`).
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
        settings: the numerical settings the runs used (:meth:`wfjax.Scenario.run_settings`:
            the resolved mode cut-off [Hz], step caps [s, m], precision, the track's bays as
            lengthened, its modes), or None.
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
    settings: Any = None

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
        """Save every array and label to ``path`` (.npz), atomically: through a uniquely
        named temporary file (:func:`wfjax.outputs.stage`; in the ``wfjax`` command, into
        the run's output set), so concurrent writers never mix their bytes."""
        from .outputs import stage

        arrays = {k: np.asarray(getattr(self, k)) for k in self._fields
                  if k not in ("flats", "contact", "settings") and getattr(self, k) is not None}
        if self.settings is not None:
            arrays["settings"] = np.array(json.dumps(self.settings))

        def write(target):
            with open(target, "wb") as fh:  # a file object: no ".npz" appended to the name
                np.savez(fh, flats=np.array(self.flats), contact=np.array(self.contact),
                         **arrays)

        stage(Path(path), write)

    @classmethod
    def load_npz(cls, path) -> SweepResult:
        """Load a result written by :meth:`save_npz`."""
        with np.load(path) as data:
            fields = {k: data[k] for k in cls._fields
                      if k not in ("flats", "contact") and k in data}
            if "sensor_quantities" in fields:
                fields["sensor_quantities"] = tuple(str(q) for q in fields["sensor_quantities"])
            if "settings" in fields:
                fields["settings"] = json.loads(str(fields["settings"]))
            return cls(flats=tuple(str(s) for s in data["flats"]),
                       contact=str(data["contact"]), **fields)

    def summary(self) -> dict:
        """JSON-ready summary per flat (kN, km/h)."""
        env = self.envelope()
        out = {"contact": self.contact, "flats": {}}
        if self.settings is not None:
            out["settings"] = self.settings
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

    def to_xarray(self, case=None, provenance: dict | None = None):
        """Every array as an ``xarray.Dataset`` with named dimensions (``flat``,
        ``speed_kmh``, ``impact_position_mm``; ``wheel``, ``realisation``, ``quantity`` x
        ``sensor_m``, ``bay`` where the sweep has them) in the CSV's units (kN, km/h, mm,
        ms), the resolved ``case`` and the ``provenance`` as JSON attributes
        (:func:`wfjax.labelled.to_xarray`). Needs ``wfjax[io]`` (xarray, pandas)."""
        return labelled.to_xarray(self, case, provenance)

    def to_dataframe(self, table: str = "runs", case=None, provenance: dict | None = None):
        """One table as a long ``pandas.DataFrame``: ``"runs"`` (the rows and units of
        :meth:`to_csv`), ``"wheels"``, ``"realisations"``, ``"sensors"`` or ``"detector"``
        (:func:`wfjax.labelled.to_dataframe`). Needs ``wfjax[io]``."""
        return labelled.to_dataframe(self, table, case, provenance)

    def to_netcdf(self, path, case=None, provenance: dict | None = None) -> Path:
        """Write :meth:`to_xarray`'s dataset to ``path`` (NetCDF 3, atomically; read it back
        with :func:`wfjax.labelled.open_netcdf`). Needs ``wfjax[io]``."""
        return labelled.to_netcdf(self, path, case, provenance)


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
            :func:`chunk_width`, from its memory); the runs, sorted by step count, are cut
            into chunks of one compiled width (a multiple of the device count), each device
            taking a contiguous slice of like step counts and the padding repeating the
            shortest run (:func:`wfjax.program.grid.lane_layout`).
        progress: print progress with ETA to stderr.
        sensors: [n_s] fixed rail positions [m] (as :func:`wfjax.simulate`): the max and min
            of each of ``sensor_quantities`` (default every one of
            :data:`wfjax.scenario.sensors.QUANTITIES`) at each, per run.
        detector: a :class:`wfjax.Detector`: its reading per bay, per run (the runs'
            windows are lengthened so that the wheel crosses every bay).
        vehicle: a :class:`wfjax.model.vehicle.Vehicle` (as :func:`wfjax.simulate`): every flat is
            swept on ``vehicle.flat_wheel``, the other wheels roll with it on the same track;
            per-wheel extremes in the ``wheel_*`` fields (a detector's peak per wheel and bay).
        roughness: rail roughness (:class:`wfjax.Roughness`, as
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
    scenario = Scenario.of(flats, contact, wheel=wheel, track=track, material=material,
                           config=config, vehicle=vehicle, roughness=roughness,
                           wheel_roughness=wheel_roughness, tracks=tracks, sensors=sensors,
                           sensor_quantities=sensor_quantities, detector=detector)
    v, pos = scenario.speeds(speeds), scenario.positions(impact_positions)
    if chunk_size is not None and (int(chunk_size) != chunk_size or chunk_size < 1):
        raise ValueError(f"chunk_size must be an integer >= 1 or None, got {chunk_size!r}")
    windows = [scenario.window_flat(f) for f in scenario.flats]
    scenario = scenario.lengthened(windows, v, pos)
    for w in windows:  # before any work; each group checks its own window again
        scenario.check_settings(w, v, pos)
    ahead = tables_ahead(scenario, cache_dir)  # alongside the modal model and the program
    program = compile_scenario(scenario, cache_dir)
    out = program.sweep(v, pos, chunk_size, progress, ahead=ahead)
    return _result(scenario, program, v, pos, out)


def _result(scenario: Scenario, program, v, pos, out: dict) -> SweepResult:
    """The :class:`SweepResult` of a sweep's per-run outputs ``out`` [f, v, p, R, ...]."""
    batch = scenario.roughness is not None or scenario.wheel_roughness is not None or (
        scenario.tracks is not None)
    det = {}
    if batch:
        det = {"realisation_max_force": out["max"], "realisation_min_force": out["min"]}
    col = {k: over_realisations(k, a) if batch else a[:, :, :, 0] for k, a in out.items()}
    fw = scenario.vehicle.flat_wheel
    preloads = np.asarray(program.data.struct.preload)
    if scenario.detector is not None:
        peak = col["det"] if scenario.per_wheel else col["det"][..., fw, :]
        loads = preloads[:, None] if scenario.per_wheel else preloads[fw]
        det |= {"detector_bays": scenario.detector.bays(), "detector_peak": peak,
                "detector_ratio": peak / loads}
    if scenario.per_wheel:
        det |= {"wheel_max_force": col["w_max"], "wheel_min_force": col["w_min"],
                "wheel_loss_of_contact": col["w_lost"].astype(bool),
                "wheel_axle_acc_peak": col["w_acc"],
                "wheel_positions": np.asarray(scenario.vehicle.positions), "flat_wheel": fw}
    if scenario.sensors is not None:
        det |= {"sensor_positions": np.asarray(program.data.sensors.positions),
                "sensor_max": col["s_max"], "sensor_min": col["s_min"],
                "sensor_quantities": program.data.sensors.quantities}
    flats = scenario.flats
    return SweepResult(
        speeds=v, impact_positions=pos, max_force=col["max"], min_force=col["min"],
        loss_of_contact=col["lost"].astype(bool), loss_of_contact_duration=col["lost_t"],
        max_residual=col["res"], flats=tuple(flat_label(f) for f in flats),
        contact=scenario.contact, axle_acc_peak=col["acc"],
        depths=np.array([float(np.asarray(f.depth)) for f in flats]),
        lengths=np.array([float(np.asarray(f.length)) for f in flats]), **det,
        settings=scenario.run_settings(np.shape(program.data.struct.track.poles)[-1]),
    )


def loss_of_contact_speed(result: SweepResult, flat_index: int = 0) -> float:
    """Lowest speed [m/s] of the sweep with loss of contact at any position (nan if none)."""
    lost = np.any(result.loss_of_contact[flat_index], axis=-1)
    return float(np.asarray(result.speeds)[lost].min()) if lost.any() else math.nan

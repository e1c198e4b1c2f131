"""Results of one simulation: :class:`SimResult` and the reduction of time histories to it."""

from __future__ import annotations

import csv
import io
import json
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from ._xla import array_module

__all__ = ["SimResult", "summarise", "summarise_run", "one_wheel", "flat_label"]


class SimResult(NamedTuple):
    """Result of :func:`simulate` (a pytree: batched by :func:`wfjax.sweep`).

    Arrays are [n_steps] along time (batched results have leading batch axes).

    Attributes:
        t: time [s], 0 at the start (static equilibrium).
        x: rail coordinate of the nominal contact point [m] (0 at a sleeper centre).
        s: wheel position relative to the impact [m] (0: flat centre at the contact point).
        force: normal contact force F [N] (>= 0).
        approach: contact approach delta = xi_W - xi_R [m].
        wheel_disp: wheel displacement at the contact point, downwards [m].
        rail_disp: rail displacement at the contact point, downwards [m].
        residual: |r(delta)| of the per-step contact equation at the solution [m].
        max_force: maximum contact force after the run-in [N].
        min_force: minimum contact force after the run-in [N].
        loss_of_contact: whether F = 0 occurred.
        loss_of_contact_duration: total time with F = 0 [s].
        speed: train speed v [m/s].
        impact_position: rail coordinate of the impact within the bay [m].
        time_step: dt [s].
        sensors: with sensors (:func:`wfjax.simulate` ``sensors=``), a dict
            {quantity: [n_steps, n_s]} of :data:`wfjax.scenario.sensors.QUANTITIES` (SI units, sign
            conventions in :mod:`wfjax.scenario.sensors`), else None.
        sensor_max, sensor_min: dicts {quantity: [n_s]}: extremes after the run-in, or None.
        detector_load: [n_steps, n_bays] the detector's calibrated shear-difference estimate
            per bay [N] (ungated), or None.
        detector_peak: [n_bays] its peak while the wheel is between the bay's bridges [N]
            (-inf for a bay the run did not cross), or None.
        detector_ratio: [n_bays] detector_peak / static wheel load P, or None.
        sensor_positions: [n_s] the sensors' rail positions [m], or None.
        axle_acc: [n_steps] acceleration of the wheelset mass M_W (the axle box), downwards
            [m/s^2] (of the flat's wheel for a vehicle).
        axle_acc_peak: max |axle_acc| after the run-in [m/s^2].
        wheel_force: a vehicle's (:class:`wfjax.model.vehicle.Vehicle`) contact forces of every
            wheel, [n_steps, n_wheels] [N] (``force`` is the flat wheel's column), or None.
        wheel_max_force, wheel_min_force: [n_wheels] their extremes after the run-in [N].
        wheel_loss_of_contact: [n_wheels] bool, F = 0 occurred at that wheel.
        wheel_axle_acc: [n_steps, n_wheels] every wheel's axle-box acceleration [m/s^2].
        wheel_axle_acc_peak: [n_wheels] max |wheel_axle_acc| after the run-in [m/s^2].
        wheel_x: [n_steps, n_wheels] every wheel's rail coordinate [m].
        support_force: on a track with hanging sleepers (``Track.ballast_gap > 0``), the
            one-sided ballast's force on each of them, upwards [n_steps, n_s] [N], else None.
        sleeper_disp: their displacement, downwards [n_steps, n_s] [m], or None.
        hanging_sleepers: their indices [n_s] (:func:`wfjax.model.sleepers.sleeper_positions`).
    """

    t: Any
    x: Any
    s: Any
    force: Any
    approach: Any
    wheel_disp: Any
    rail_disp: Any
    residual: Any
    max_force: Any
    min_force: Any
    loss_of_contact: Any
    loss_of_contact_duration: Any
    speed: Any
    impact_position: Any
    time_step: Any
    sensors: Any = None
    sensor_max: Any = None
    sensor_min: Any = None
    detector_load: Any = None
    detector_peak: Any = None
    detector_ratio: Any = None
    sensor_positions: Any = None
    axle_acc: Any = None
    axle_acc_peak: Any = None
    wheel_force: Any = None
    wheel_max_force: Any = None
    wheel_min_force: Any = None
    wheel_loss_of_contact: Any = None
    wheel_axle_acc: Any = None
    wheel_axle_acc_peak: Any = None
    wheel_x: Any = None
    support_force: Any = None
    sleeper_disp: Any = None
    hanging_sleepers: Any = None

    def summary(self) -> dict:
        """JSON-ready summary with practical units (kN, km/h, mm, ms)."""
        return {
            "speed_kmh": float(self.speed) * 3.6,
            "impact_position_mm": float(self.impact_position) * 1e3,
            "max_force_kN": float(self.max_force) / 1e3,
            "min_force_kN": float(self.min_force) / 1e3,
            "loss_of_contact": bool(self.loss_of_contact),
            "loss_of_contact_duration_ms": float(self.loss_of_contact_duration) * 1e3,
            "time_step_us": float(self.time_step) * 1e6,
            "n_steps": int(np.shape(self.t)[-1]),
            "max_contact_residual_m": float(np.max(self.residual)),
            "axle_box_acceleration_peak_m_s2": float(self.axle_acc_peak),
            **self._wheel_summary(),
            **self._detector_summary(),
            **self._support_summary(),
        }

    def _support_summary(self) -> dict:
        if self.support_force is None:
            return {}
        force = np.asarray(self.support_force)
        dt = float(self.time_step)
        return {"hanging_sleepers": [
            {"sleeper": int(i), "max_support_force_kN": float(f.max()) / 1e3,
             "open_ms": float(np.sum(f <= 0.0)) * dt * 1e3,
             "max_sleeper_disp_mm": float(np.max(np.asarray(self.sleeper_disp)[:, k])) * 1e3}
            for k, (i, f) in enumerate(zip(np.asarray(self.hanging_sleepers), force.T,
                                           strict=True))]}

    def _wheel_summary(self) -> dict:
        if self.wheel_force is None:
            return {}
        return {"wheels": [
            {"wheel": i, "max_force_kN": float(mx) / 1e3, "min_force_kN": float(mn) / 1e3,
             "loss_of_contact": bool(lost), "axle_box_acceleration_peak_m_s2": float(acc)}
            for i, (mx, mn, lost, acc) in enumerate(zip(
                np.asarray(self.wheel_max_force), np.asarray(self.wheel_min_force),
                np.asarray(self.wheel_loss_of_contact), np.asarray(self.wheel_axle_acc_peak),
                strict=True))]}

    def _detector_summary(self) -> dict:
        out = {}
        if self.sensor_max is not None:
            out["sensor_max"] = {k: np.asarray(v).tolist() for k, v in self.sensor_max.items()}
            out["sensor_min"] = {k: np.asarray(v).tolist() for k, v in self.sensor_min.items()}
        if self.detector_peak is not None:
            out["detector_peak_kN"] = (np.asarray(self.detector_peak) / 1e3).tolist()
            out["detector_ratio"] = np.asarray(self.detector_ratio).tolist()
        return out

    def to_csv(self) -> str:
        """The time histories as CSV text (SI units, one row per step; a vehicle's every
        wheel's force and axle-box acceleration as ``force_N@wheel<i>``,
        ``axle_acc_m_s2@wheel<i>``; hanging sleepers' ``support_force_N@sleeper<i>`` and
        ``sleeper_disp_m@sleeper<i>``)."""
        buf = io.StringIO()
        w = csv.writer(buf)
        head = ["t_s", "x_m", "s_m", "force_N", "approach_m", "wheel_disp_m", "rail_disp_m",
                "axle_acc_m_s2"]
        cols = [np.asarray(getattr(self, k)) for k in
                ("t", "x", "s", "force", "approach", "wheel_disp", "rail_disp", "axle_acc")]
        if self.wheel_force is not None:
            n = np.shape(self.wheel_force)[-1]
            head += [f"force_N@wheel{i}" for i in range(n)]
            head += [f"axle_acc_m_s2@wheel{i}" for i in range(n)]
            cols += list(np.asarray(self.wheel_force).T) + list(np.asarray(self.wheel_axle_acc).T)
        if self.support_force is not None:
            idx = np.asarray(self.hanging_sleepers)
            head += [f"support_force_N@sleeper{i}" for i in idx]
            head += [f"sleeper_disp_m@sleeper{i}" for i in idx]
            cols += list(np.asarray(self.support_force).T) + list(np.asarray(self.sleeper_disp).T)
        w.writerow(head)
        for row in zip(*cols, strict=True):
            w.writerow([f"{v:.9g}" for v in row])
        return buf.getvalue()

    def sensors_to_csv(self) -> str:
        """The sensors' histories as CSV text: t_s, x_m, then ``<quantity>@<x>m`` (SI)."""
        if self.sensors is None:
            raise ValueError("this result has no sensors (simulate(..., sensors=[...]))")
        xs = np.asarray(self.sensor_positions)
        names = list(self.sensors)
        buf = io.StringIO()
        w = csv.writer(buf)
        w.writerow(["t_s", "x_m"] + [f"{q}@{x:g}m" for q in names for x in xs])
        cols = [np.asarray(self.t), np.asarray(self.x)] + [
            np.asarray(self.sensors[q])[:, i] for q in names for i in range(xs.size)]
        for row in zip(*cols, strict=True):
            w.writerow([f"{v:.9g}" for v in row])
        return buf.getvalue()

    def to_json(self) -> str:
        """:meth:`summary` as JSON text."""
        return json.dumps(self.summary(), indent=2)


def summarise(hist: dict, speed, impact_position, dt, run_in_steps, quantities=(),
              preload=None, end_steps=None) -> SimResult:
    """Reduce histories to a :class:`SimResult` (jnp, works batched under vmap; numpy for
    host histories).

    ``quantities`` names the rows of the sensor outputs in ``hist`` (if any); ``preload`` [N]
    is the static wheel load the detector's ratio refers to. The extremes, loss of contact
    and axle-box peak count the steps ``run_in_steps <= n < end_steps`` (default: to the
    end of the histories).
    """
    xp = array_module(hist["force"])  # numpy for one run's host histories (simulate)
    sensor = {}
    if "sensor_max" in hist:
        def split(a, axis):
            return {q: xp.take(a, i, axis=axis) for i, q in enumerate(quantities)}

        sensor = {"sensor_max": split(hist["sensor_max"], -2),
                  "sensor_min": split(hist["sensor_min"], -2)}
        if "sensors" in hist:
            sensor["sensors"] = split(hist["sensors"], -2)
    if "detector_peak" in hist:
        sensor["detector_peak"] = hist["detector_peak"]
        sensor["detector_ratio"] = hist["detector_peak"] / preload
        if "detector_load" in hist:
            sensor["detector_load"] = hist["detector_load"]
    f = hist["force"]
    n = f.shape[-1]
    after = counted_steps(n, run_in_steps, end_steps, xp)
    f_after = xp.where(after, f, xp.nan)
    lost = after & (f <= 0)
    acc = hist.get("axle_acc", xp.zeros_like(f))
    return SimResult(
        axle_acc=acc, axle_acc_peak=xp.max(xp.where(after, xp.abs(acc), 0.0), axis=-1),
        t=hist["t"], x=hist["x"], s=hist["s"], force=f, approach=hist["approach"],
        wheel_disp=hist["wheel_disp"], rail_disp=hist["rail_disp"], residual=hist["residual"],
        max_force=xp.nanmax(f_after, axis=-1), min_force=xp.nanmin(f_after, axis=-1),
        loss_of_contact=xp.any(lost, axis=-1),
        loss_of_contact_duration=xp.sum(lost, axis=-1) * dt,
        speed=xp.asarray(speed, dtype=float), impact_position=xp.asarray(impact_position,
                                                                           dtype=float),
        time_step=xp.asarray(dt, dtype=float), **sensor,
    )


def counted_steps(n_steps: int, run_in_steps, end_steps=None, xp=jnp):
    """[n_steps] bool: the steps a summary counts, ``run_in_steps <= n < end_steps``."""
    n = xp.arange(n_steps)
    return (n >= run_in_steps) if end_steps is None else (n >= run_in_steps) & (n < end_steps)


def summarise_run(hist: dict, flat_wheel: int, speed, impact_position, dt, run_in_steps,
                      quantities=(), preload=None, end_steps=None) -> SimResult:
    """:func:`summarise` of a run's histories ([n_steps, n_wheels]; one wheel is a vehicle
    of one): the main fields are the reference wheel's (``flat_wheel``), the ``wheel_*``
    fields every wheel's.

    ``preload`` [n_wheels] N: the detector's ratio divides each wheel's peak by its own load.
    """
    per_wheel = ("x", "s", "force", "approach", "wheel_disp", "rail_disp", "residual",
                 "axle_acc")
    main = {k: (v[:, flat_wheel] if k in per_wheel else v) for k, v in hist.items()}
    main.pop("detector_peak", None)
    res = summarise(main, speed, impact_position, dt, run_in_steps, quantities,
                    end_steps=end_steps)
    xp = array_module(hist["force"])
    f, acc = hist["force"], hist["axle_acc"]
    after = counted_steps(f.shape[0], run_in_steps, end_steps, xp)[:, None]
    extra = {}
    if "detector_peak" in hist:
        extra = {"detector_peak": hist["detector_peak"],
                 "detector_ratio": hist["detector_peak"] / xp.asarray(preload)[:, None]}
        if "detector_load" in hist:
            extra["detector_load"] = hist["detector_load"]
    return res._replace(
        wheel_force=f, wheel_max_force=xp.max(xp.where(after, f, -xp.inf), axis=0),
        wheel_min_force=xp.min(xp.where(after, f, xp.inf), axis=0),
        wheel_loss_of_contact=xp.any(after & (f <= 0), axis=0),
        wheel_axle_acc=acc, wheel_axle_acc_peak=xp.max(xp.where(after, xp.abs(acc), 0.0),
                                                       axis=0),
        wheel_x=hist["x"], **extra)


def one_wheel(res: SimResult, flat_wheel: int = 0) -> SimResult:
    """A :func:`summarise_run` result as the paper's single wheel reports it: without the
    ``wheel_*`` fields, the detector's peaks [n_bays] of the reference wheel only."""
    extra = {}
    if res.detector_peak is not None:
        extra = {"detector_peak": res.detector_peak[..., flat_wheel, :],
                 "detector_ratio": res.detector_ratio[..., flat_wheel, :]}
    return res._replace(wheel_force=None, wheel_max_force=None, wheel_min_force=None,
                        wheel_loss_of_contact=None, wheel_axle_acc=None,
                        wheel_axle_acc_peak=None, wheel_x=None, **extra)


def flat_label(flat) -> str:
    """A short human label of a :class:`wfjax.Flat` (mm), e.g. ``"new d=0.90mm"``."""
    d = float(flat.depth) * 1e3
    if flat.kind == "rounded":
        return f"rounded d={d:.2f}mm l={float(flat.length) * 1e3:.1f}mm"
    if flat.kind == "new":
        return f"new d={d:.2f}mm"
    return f"{flat.kind} d={d:.2f}mm"


"""Physics guards: numerical settings that cannot keep the maximum contact force within 3 % of
the converged reference are refused before any work, with one line naming the setting, its
value, the bound and why (or, with ``SimConfig.allow_inaccurate``, run with a warning that is
recorded in the output's provenance).

Each bound is a scale of the case at hand times a constant read off the accuracy table of
``docs/convergence.md`` ("Physics guards", where the derivation is written out):

- time step: ``dt <= STEP_FACTOR / f_W``, f_W the wheel's highest natural frequency on the
  Hertz spring, and ``v dt <= TRAVEL_FACTOR 2a``, 2a the length of the contact patch that
  filters the surface it rolls over (both :func:`scales`);
- track modes: ``track_max_frequency >= MODES_FACTOR f_W``;
- rail mesh: elements no longer than ``1 / MESH_FACTOR`` of the rail's bending wavelength at
  the highest kept mode (:func:`bending_wavelength`);
- contact element (3D and 2D contact): no longer than ``ELEMENT_FACTOR`` 2a;
- track length: every wheel's path at least ``END_FACTOR / beta`` from the clamped rail ends,
  every sensor ``SENSOR_END_FACTOR / beta`` (:func:`wfjax.scenario.sensors.check_positions`;
  ``NETWORK_END_FACTOR`` and ``NETWORK_SENSOR_END_FACTOR`` from end networks),
  1/beta the decay length of the rail on its supports (:func:`decay_length`), and both off
  the absorbing sleepers (``Track.absorbing_sleepers``, :func:`absorbing_length`).
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import math
import warnings

import numpy as np

from .. import params as P
from ..contact.geometry3d import elliptic_hertz
from ..model import ends
from ..params import READING_BAYS, SUPPORT_FIELDS, Material, SimConfig, Track, Wheel

ACCURACY = 0.03  # the largest max-force error against the reference that runs without a word
STEP_FACTOR = 0.4  # dt f_W
TRAVEL_FACTOR = 0.3  # v dt / 2a
MODES_FACTOR = 0.85  # track_max_frequency / f_W
MESH_FACTOR = 3.0  # rail elements per bending wavelength at the highest kept mode
ELEMENT_FACTOR = 0.15  # contact element / 2a
END_FACTOR = 3.0  # a wheel path's distance to the clamped ends x beta
SENSOR_END_FACTOR = 8.5  # a sensor's distance to the clamped ends x beta
# the same to end networks (Track.ends), which reflect nothing: wheel paths 0.5 / beta
# (forces as at 3 / beta, within 0.022 % of 70 bays from 0.25 / beta), sensors 3 / beta
# (receptances within 0.58 % of the reference, 1.50 % at 1 / beta), a detector on at least
# params.NETWORK_READING_BAYS = 24 (its reading within 0.24 % of 70 bays' at 40-200 km/h,
# 0.38-0.47 % on 10-14);
# benchmarks/network_margins.py and accuracy_table.py, docs/convergence.md "End networks"
NETWORK_END_FACTOR = 0.5
NETWORK_SENSOR_END_FACTOR = 3.0
RECEPTANCE_BAYS = 140  # direct point receptances within 0.5 % of an 800-bay track's, 20 Hz -
# 2 kHz outside the pinned-pinned band 900-990 Hz, where no finite track converges pointwise
# (benchmarks/receptance_length.py)


class InaccurateSettings(ValueError):
    """A numerical setting outside what keeps the maximum force within 3 % of the reference."""


class AccuracyWarning(UserWarning):
    """A guard's finding, run anyway because ``SimConfig.allow_inaccurate`` is set."""


@dataclasses.dataclass(frozen=True)
class Scales:
    """The case's physical scales that the guards compare settings with.

    Attributes:
        contact_length: 2a, the Hertz contact length along the rail at the static load [m].
        wheel_frequency: f_W, the wheel's highest natural frequency on the Hertz spring [Hz].
        decay_length: 1/beta, the rail's static decay length on its supports [m].
    """

    contact_length: float
    wheel_frequency: float
    decay_length: float


def bending_wavelength(track: Track, frequency: float) -> float:
    """Euler-Bernoulli bending wavelength of the free rail [m] at ``frequency`` [Hz]:
    2 pi (EI / (m omega^2))^(1/4)."""
    omega = 2 * math.pi * float(frequency)
    return 2 * math.pi * (float(track.bending_stiffness)
                          / (float(track.rail_mass) * omega ** 2)) ** 0.25


def extendable(track: Track) -> bool:
    """Whether ``track``'s length may grow (``Track.n_bays`` is the least length): every
    support field a scalar; per-sleeper supports fix it."""
    return all(np.ndim(getattr(track, name)) == 0 for name in SUPPORT_FIELDS)


def bays_reaching(track: Track, half: float) -> int:
    """The least even ``n_bays`` whose rail reaches ``half`` [m] either side of the middle
    sleeper."""
    return 2 * math.ceil(half / float(track.sleeper_spacing) - 1e-9)


def has_network(track: Track) -> bool:
    """Whether ``track`` ends in networks (``Track.ends``, :func:`wfjax.model.ends.resolved`)."""
    return ends.resolved(track).ends == "network"


def at_least(track: Track, half: float) -> Track:
    """``track`` with the least even ``n_bays`` (never fewer than its own) whose rail reaches
    ``half`` [m] either side of the middle sleeper, and at least
    :data:`wfjax.params.ABSORBING_BAYS` with absorbing (or clamped) ends."""
    n = max(bays_reaching(track, half), 0 if has_network(track) else P.ABSORBING_BAYS)
    most = next(f.metadata["high"] for f in dataclasses.fields(Track) if f.name == "n_bays")
    if n > most:
        length = n * float(track.sleeper_spacing)
        raise ValueError(f"the case needs a track of {n} bays ({length:g} m: its wheels, "
                         f"sensors or detector reach +-{half:.2f} m with the margins from "
                         f"the clamped ends), more than track.n_bays allows ({most})")
    return track if n <= int(track.n_bays) else dataclasses.replace(track, n_bays=n)


def holding_instruments(track: Track, sensors, detector=None) -> Track:
    """``track`` lengthened (scalar supports only) so that every sensor [m] and bridge of
    ``detector`` (a :class:`wfjax.scenario.sensors.Detector`) keeps :func:`sensor_margin`
    from the clamped ends, and to at least :data:`wfjax.params.READING_BAYS` bays with a
    detector (:data:`wfjax.params.NETWORK_READING_BAYS` with end networks); non-finite
    positions are left to the sensors' own check."""
    x = [] if sensors is None else list(np.ravel(np.asarray(sensors, dtype=float)))
    least = P.NETWORK_READING_BAYS if has_network(track) else READING_BAYS
    if detector is not None and extendable(track) and int(track.n_bays) < least:
        track = dataclasses.replace(track, n_bays=least)
    if detector is not None:
        a, b = detector.gauges(float(track.sleeper_spacing))
        x += [float(a[0]), float(b[-1])]
    x = [abs(v) for v in x if math.isfinite(v)]
    if not x or not extendable(track):
        return track
    return at_least(track, max(x) + sensor_margin(track) + 1e-3)


def decay_length(track: Track) -> float:
    """1/beta [m] of the rail on its supports (pad and ballast in series, smeared over the
    bay; their mean when they vary): beta = (k / (4 EI))^(1/4)."""
    kp = np.asarray(track.pad_stiffness, dtype=float)
    kb = np.asarray(track.ballast_stiffness, dtype=float)
    with np.errstate(divide="ignore"):  # a void sleeper: no support there
        k = float(np.mean(1.0 / (1.0 / kp + 1.0 / kb))) / float(track.sleeper_spacing)
    return float((4 * float(track.bending_stiffness) / k) ** 0.25)


def scales(wheel: Wheel, track: Track, material: Material) -> Scales:
    """The :class:`Scales` of a wheel on a track, from one elliptic Hertz contact at the
    static load P: 2a along the rail, k_H = 1.5 P / delta, and f_W = sqrt((k_W + k_H) / m_W)
    / 2 pi, the small mass m_W between the wheel's spring k_W and the Hertz spring, held at
    the wheelset and the rail (the stiffest oscillator of the model; the rail's modes are
    propagated exactly and do not limit the step)."""
    a, _, delta, _ = elliptic_hertz(float(wheel.preload), float(wheel.radius),
                                    float(track.rail_head_radius), material)
    k = float(wheel.contact_stiffness) + 1.5 * float(wheel.preload) / float(delta)
    return Scales(2 * float(a), math.sqrt(k / float(wheel.small_mass)) / (2 * math.pi),
                  decay_length(track))


def absorbing_length(track: Track) -> float:
    """[m] of rail at each end over the absorbing sleepers (``Track.absorbing_sleepers``)
    and the clamped end's bay: a track whose damping is not the user's (0 with networks)."""
    n = int(ends.resolved(track).absorbing_sleepers)
    return (n + 1) * float(track.sleeper_spacing) if n else 0.0


def end_margin(track: Track) -> float:
    """The distance [m] every wheel's path keeps from the ends: END_FACTOR decay lengths from
    clamped ends (NETWORK_END_FACTOR from end networks), and off the absorbing sleepers
    (:func:`absorbing_length`)."""
    factor = NETWORK_END_FACTOR if has_network(track) else END_FACTOR
    return max(factor * decay_length(track), absorbing_length(track))


def sensor_margin(track: Track) -> float:
    """The distance [m] every sensor keeps from the ends (longer than the wheels': a seat
    force or a shear feels the ends' reflections more than the contact force;
    NETWORK_SENSOR_END_FACTOR decay lengths from end networks), and off the absorbing
    sleepers."""
    factor = NETWORK_SENSOR_END_FACTOR if has_network(track) else SENSOR_END_FACTOR
    return max(factor * decay_length(track), absorbing_length(track))


def step_findings(config: SimConfig, speeds, sc: Scales) -> list[str]:
    """One line for the worst speed whose time step exceeds ``STEP_FACTOR / f_W`` or whose
    travel per step exceeds ``TRAVEL_FACTOR`` 2a (auto settings: the force's, unless
    ``config`` is resolved)."""
    config, worst = config.resolved(), None
    for v in np.atleast_1d(np.asarray(speeds, dtype=float)):
        v = float(v)
        dt = config.time_step_for(v)
        bound = min(STEP_FACTOR / sc.wheel_frequency, TRAVEL_FACTOR * sc.contact_length / v)
        if dt > bound and (worst is None or dt / bound > worst[0]):
            worst = (dt / bound, v, dt, bound)
    if worst is None:
        return []
    _, v, dt, bound = worst
    if config.time_step is not None:
        key, value = "config.time_step", f"{config.time_step * 1e6:g} us"
    elif config.max_time_step * v <= config.max_travel_step:
        key, value = "config.max_time_step", f"{config.max_time_step * 1e6:g} us"
    else:
        key, value = "config.max_travel_step", f"{config.max_travel_step * 1e3:g} mm"
    return [f"{key} = {value} gives a time step of {dt * 1e6:.3g} us ({v * dt * 1e3:.3g} mm) "
            f"at {v * 3.6:.4g} km/h, above {bound * 1e6:.3g} us: the step must stay below "
            f"{STEP_FACTOR} / f_W = {STEP_FACTOR / sc.wheel_frequency * 1e6:.3g} us (f_W = "
            f"{sc.wheel_frequency:.0f} Hz, the wheel's small-mass resonance on the Hertz "
            f"spring) and travel at most {TRAVEL_FACTOR} x the contact length 2a = "
            f"{sc.contact_length * 1e3:.1f} mm"]


def track_findings(track: Track, config: SimConfig, sc: Scales) -> list[str]:
    """Lines for a mode cut-off below ``MODES_FACTOR f_W`` and a rail mesh coarser than
    ``MESH_FACTOR`` elements per bending wavelength at the cut-off (auto settings: the
    force's, unless ``config`` is resolved)."""
    config, out = config.resolved(), []
    f_min = MODES_FACTOR * sc.wheel_frequency
    if config.track_max_frequency < f_min:
        out.append(f"config.track_max_frequency = {config.track_max_frequency:g} Hz is below "
                   f"{f_min:.0f} Hz = {MODES_FACTOR} f_W, the wheel's small-mass resonance "
                   "on the Hertz spring, which the kept track modes must reach")
    h = float(track.sleeper_spacing) / int(track.elements_per_bay)
    lam = bending_wavelength(track, config.track_max_frequency)
    if h > lam / MESH_FACTOR:
        need = math.ceil(MESH_FACTOR * float(track.sleeper_spacing) / lam)
        out.append(f"track.elements_per_bay = {int(track.elements_per_bay)} gives "
                   f"{h * 1e3:.0f} mm rail elements, longer than {lam / MESH_FACTOR * 1e3:.0f} "
                   f"mm = 1/{MESH_FACTOR:g} of the bending wavelength at the highest kept mode "
                   f"({config.track_max_frequency:g} Hz): use at least {need}")
    return out


def element_findings(contact: str, config: SimConfig, sc: Scales) -> list[str]:
    """A line for a contact element above ``ELEMENT_FACTOR`` 2a (3D and 2D contact)."""
    bound = ELEMENT_FACTOR * sc.contact_length
    if contact not in ("3d", "2d") or config.contact_element <= bound:
        return []
    return [f"config.contact_element = {config.contact_element * 1e3:g} mm is above "
            f"{bound * 1e3:.2f} mm = {ELEMENT_FACTOR} x the Hertz contact length "
            f"2a = {sc.contact_length * 1e3:.1f} mm"]


def end_findings(track: Track, lo: float, hi: float) -> list[str]:
    """A line when the wheels' path [``lo``, ``hi``] [m] comes within :func:`end_margin` of
    the rail's ends."""
    half = 0.5 * int(track.n_bays) * float(track.sleeper_spacing)
    margin = end_margin(track)
    if lo >= -half + margin and hi <= half - margin:
        return []
    need = bays_reaching(track, max(hi, -lo) + margin)
    ends_text = (f"{NETWORK_END_FACTOR:g} / beta) of the end networks" if has_network(track)
                 else f"the larger of {END_FACTOR:g} / beta and the absorbing sleepers) of the "
                      "clamped rail ends")
    return [f"track.n_bays = {int(track.n_bays)}: the wheels' path [{lo:.2f}, {hi:.2f}] m "
            f"comes within {margin:.2f} m ({ends_text} at +-{half:.2f} m, where their "
            f"reflections reach the contact: use n_bays >= {need}"]


_SHOWN: dict = {}  # the warnings registry of the guards' findings
_NOTES: contextvars.ContextVar[list | None] = contextvars.ContextVar("wfjax_guard_notes",
                                                                      default=None)


@contextlib.contextmanager
def recorded():
    """Collect the findings run anyway inside the block (yields the list, for provenance)."""
    notes: list[str] = []
    token = _NOTES.set(notes)
    try:
        yield notes
    finally:
        _NOTES.reset(token)


def notes() -> list[str]:
    """The findings run anyway so far inside :func:`recorded` (empty outside)."""
    return list(_NOTES.get() or [])


def enforce(findings: list[str], config: SimConfig) -> None:
    """Refuse the first finding (one line), or warn and record every one when
    ``config.allow_inaccurate`` is set."""
    if not findings:
        return
    if not config.allow_inaccurate:
        raise InaccurateSettings(
            f"{findings[0]}; this keeps the max contact force within "
            f"{ACCURACY * 100:.0f} % of the converged reference (docs/convergence.md, "
            "Physics guards); --allow-inaccurate (config.allow_inaccurate = true) runs it "
            "anyway")
    bucket = _NOTES.get()
    for line in findings:  # shown once per finding, however many checks meet it
        warnings.warn_explicit(AccuracyWarning(line), AccuracyWarning, "wfjax physics guard", 0,
                               module=__name__, registry=_SHOWN)
        if bucket is not None and line not in bucket:
            bucket.append(line)

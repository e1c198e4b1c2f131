"""Passages of a chosen train over a detector, simulated in full: ``wfjax detector
--passage-csv`` and the validation's truth.

Every bogie (wheels closer than :data:`wfjax.identify.pipeline.GROUP_GAP`) runs coupled on
its own track window (:func:`wfjax.identify.forward.coupled_readings`) with its own
independent rail roughness realisation (ISO 3095 limit) and support scatter, or, over one
site (``site_seed``), all on the site's supports and rail, batched over the bogies
(:func:`wfjax.identify.forward.coupled_batch`); each flat
strikes at a continuous random rail coordinate over one wheel circumference; the readings
get relative Gaussian noise.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..params import Wheel
from ..scenario.sensors import Detector
from . import forward as fwd
from .passage import Passage

__all__ = ["TrainFlat", "simulate_passage", "truth_of", "parse_flats"]


@dataclasses.dataclass(frozen=True)
class TrainFlat:
    """A flat on wheel ``wheel``: ``kind`` new/rounded, ``length`` [m], ``factor`` l / l0
    (rounded), ``impact`` rail coordinate [m] where it strikes (None: random)."""

    wheel: int
    kind: str
    length: float
    factor: float = 1.76
    impact: float | None = None


def parse_flats(text: str) -> list[TrainFlat]:
    """``"wheel:kind:length_mm[:factor]"`` items, comma separated (``"1:new:60,2:rounded:80"``);
    ValueError naming the bad item."""
    out = []
    for item in (s.strip() for s in text.split(",") if s.strip()):
        parts = item.split(":")
        try:
            if len(parts) not in (3, 4) or parts[1] not in ("new", "rounded"):
                raise ValueError
            wheel, length = int(parts[0]), float(parts[2]) * 1e-3
            factor = float(parts[3]) if len(parts) == 4 else 1.76
            if wheel < 0 or not 0.005 <= length <= 0.13 or factor < math.pi / 2:
                raise ValueError
        except ValueError:
            raise ValueError(f"flats: item {item!r}: allowed: wheel:kind:length_mm[:l/l0], "
                             "kind new or rounded, length 5-130 mm, l/l0 >= pi/2") from None
        out.append(TrainFlat(wheel, parts[1], length, factor))
    return out


def _groups(positions):
    from .pipeline import _groups

    return _groups(np.asarray(positions, float))


def _layouts(positions, groups):
    from .pipeline import _layouts

    return _layouts(np.asarray(positions, float), groups)


def _truth_flat(t: dict, radius: float):
    """The flat of a wheel's truth (a round wheel: a new 4 mm flat, no impact)."""
    if t["kind"] == "none":
        return fwd.round_wheel(radius)
    return fwd.flat_of(t["kind"], t["length"], t["factor"], radius)


def truth_of(n_wheels: int, flats: list[TrainFlat], seed: int = 0,
             detector: Detector | None = None, wheel: Wheel | None = None) -> list[dict]:
    """Per wheel the truth :func:`simulate_passage` draws with ``seed`` (kind, length [m],
    l / l0, depth [m], impact [m]), without simulating (its peak force is not known here)."""
    wheel, detector = wheel or Wheel(), detector or Detector(5, -1)
    return _draw_truth(n_wheels, flats, np.random.default_rng(seed + 104729), detector,
                       float(wheel.radius))


def _draw_truth(n_wheels: int, flats, rng, detector: Detector, radius: float) -> list[dict]:
    """Per wheel its truth; each flat without a given impact strikes at a rail coordinate
    drawn uniformly over one circumference from the detector's first bay (``rng``: one draw
    per wheel, round ones too)."""
    by_wheel = {f.wheel: f for f in flats}
    if any(w >= n_wheels for w in by_wheel):
        raise ValueError(f"flats: wheel index beyond the layout's {n_wheels} wheels")
    ls = float(fwd.TRACK.sleeper_spacing)
    x0 = int(detector.bays()[0]) * ls  # as the identification's phase grid
    truth = []
    for i in range(n_wheels):
        f = by_wheel.get(i)
        x = x0 + rng.uniform(0, 2 * math.pi * radius) if f is None or f.impact is None \
            else f.impact
        kind, length, factor = ("none", 0.0, 1.0) if f is None else (f.kind, f.length,
                                                                    f.factor)
        depth = 0.0 if f is None else float(fwd.depth_of(kind, length, factor, radius))
        truth.append({"wheel": i, "kind": kind, "length": length, "factor": factor,
                      "depth": depth, "impact": float(x)})
    return truth


def simulate_passage(positions, flats: list[TrainFlat], speed: float,
                     detector: Detector | None = None, noise: float = 0.03,
                     seed: int = 0, scatter_cv: float = 0.1, contact: str = "hertz-trajectory",
                     wheel: Wheel | None = None, cache_dir=None, site_seed: int | None = None
                     ) -> tuple[Passage, list[dict]]:
    """(the :class:`Passage`, per wheel its truth: kind, length [m], depth [m], impact [m]).

    ``positions`` [n] m behind the leading wheel; ``flats``: the flat wheels (the others
    round); ``speed`` [m/s]; ``noise``: relative standard deviation of the readings;
    ``seed``: every random draw (impacts, roughness, supports, noise) derives from it,
    independently of anything :func:`wfjax.identify.identify` samples. ``site_seed``: when
    given, the detector site's support scatter and rail roughness derive from it instead, the
    same for every bogie (one site: every passage over it with the same ``site_seed`` sees
    the same supports and rail; the impacts and the noise still follow ``seed``).
    """
    from ..model.supports import scatter
    from ..scenario import roughness as rough_mod

    wheel, detector = wheel or Wheel(), detector or Detector(5, -1)
    radius = float(wheel.radius)
    positions = np.asarray(positions, float)
    rng = np.random.default_rng(seed + 104729)
    truth = _draw_truth(positions.size, flats, rng, detector, radius)
    readings = np.zeros((positions.size, detector.n_bays))
    peaks = np.zeros(positions.size)
    groups = _groups(positions)
    if site_seed is not None:  # one site: every bogie on the same track and rail, batched
        track = fwd.TRACK if scatter_cv <= 0 else scatter(fwd.TRACK, 900001 + 7 * site_seed,
                                                        scatter_cv)
        rough = rough_mod.generate(rough_mod.ISO3095_LIMIT, 700001 + 10007 * site_seed,
                                   fwd.ROUGHNESS_SPAN, x_start=-fwd.ROUGHNESS_SPAN / 2)
        for layout, members in _layouts(positions, groups).items():
            cases = [([_truth_flat(truth[i], radius) for i in g],
                      [truth[i]["impact"] for i in g]) for g in members]
            r, p = fwd.coupled_batch(cases, np.array(layout), speed, detector, contact,
                                     rough, track, wheel, cache_dir=cache_dir)
            for g, rg, pg in zip(members, r, p, strict=True):
                readings[g], peaks[g] = rg, pg
        groups = []
    for g, group in enumerate(groups):  # each bogie its own track window, supports and rail
        s_track, s_rough = seed * 7 + g + 1, 10007 * (seed + 1) + g
        track = fwd.TRACK if scatter_cv <= 0 else scatter(fwd.TRACK, s_track, scatter_cv)
        rough = rough_mod.generate(rough_mod.ISO3095_LIMIT, s_rough, fwd.ROUGHNESS_SPAN,
                                   x_start=-fwd.ROUGHNESS_SPAN / 2)
        fl = [_truth_flat(truth[i], radius) for i in group]
        r, p = fwd.coupled_readings(fl, [truth[i]["impact"] for i in group],
                                    positions[group] - positions[group[0]], speed, detector,
                                    contact, rough, track, wheel, cache_dir=cache_dir)
        readings[group], peaks[group] = r, p
    for i, t in enumerate(truth):
        t["peak_force"] = float(peaks[i])
    noisy = readings * (1 + noise * rng.standard_normal(readings.shape))
    return Passage(float(speed), positions, detector.bays(), noisy, detector.gauge_offset,
                   detector.calibration), truth

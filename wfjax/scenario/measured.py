"""One measurement, two inputs: a gauge's records (:mod:`wfjax.sections`) split into the measured
3D flat (:meth:`wfjax.params.Flat.from_sections`) and the wheel's out-of-roundness on the rest
of the circumference (a periodic :class:`wfjax.scenario.roughness.Roughness`).

Rules (docs/measured_flats.md):

* **Locating the flat.** The band record m(x) is the mean of the records, each less its
  median. Its deepest point (after a 5-sample moving average) is the flat; the window runs from
  it both ways to where m(x) first rises above -5 % of that depth, plus
  :data:`WINDOW_MARGIN_MM` on each side. A given window (``window_mm``, record positions) must
  contain that deepest point, else it misses the flat.
* **The flat.** Inside the window each record, less its background (the straight line between
  the means of the :data:`BACKGROUND_SAMPLES` samples just outside either end), with the sign
  turned (material missing is positive), centred on the deepest sample of the band record.
* **The out-of-roundness.** The mean of the records whose lateral position lies within
  +-``contact_half_width_mm`` (the static contact's half width; at least the line nearest
  y = 0), less its mean outside the window; zero inside the window, rising to full over
  ``taper_mm`` outside either end with a raised cosine; positive outward (surface raised) as
  :mod:`wfjax.scenario.roughness` reads it, sample 0 at the flat centre (s = 0).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..params import Flat
from ..sections import Records, SectionsError
from .roughness import Roughness

__all__ = ["MeasuredFlat", "split", "locate_window", "from_values", "case_wheel_roughness"]

WINDOW_MARGIN_MM = 5.0
BACKGROUND_SAMPLES = 5
EDGE_FRACTION = 0.05


class MeasuredFlat(NamedTuple):
    """A measurement split (module docstring).

    Attributes:
        flat: the ``"sections"`` :class:`wfjax.params.Flat`.
        wheel_roughness: the periodic out-of-roundness (:class:`Roughness`, [m]).
        window_mm: (start, end) record positions [mm] of the flat's window.
        centre_mm: record position [mm] of the flat centre.
    """

    flat: Flat
    wheel_roughness: Roughness
    window_mm: tuple
    centre_mm: float


def _band(rec: Records) -> np.ndarray:
    dev = rec.deviation_um - np.median(rec.deviation_um, axis=1, keepdims=True)
    return dev.mean(axis=0)


def locate_window(rec: Records, window_mm=None) -> tuple[int, int, int]:
    """(first, centre, last) sample indices of the flat's window in the records, on the
    periodic index (``first`` may be negative, ``last`` may exceed n - 1)."""
    band = _band(rec)
    n = band.size
    smooth = np.convolve(np.concatenate([band[-2:], band, band[:2]]), np.ones(5) / 5, "valid")
    centre = int(np.argmin(smooth))
    depth = -smooth[centre]
    if depth <= 0:
        raise SectionsError(f"{rec.files[0]}: the records have no dip: no flat to locate")
    if window_mm is not None:
        a, b = (float(v) for v in window_mm)
        x = rec.position_mm
        inside = (x >= a) & (x <= b)
        if not a < b or not inside.any():
            raise SectionsError(f"--section-window-mm: ({a!r}, {b!r}) mm is not a window of "
                                f"the records ({float(x[0])!r} to {float(x[-1])!r} mm)")
        first, last = int(np.flatnonzero(inside)[0]), int(np.flatnonzero(inside)[-1])
        if not first <= centre <= last:
            raise SectionsError(f"--section-window-mm: ({a!r}, {b!r}) mm misses the flat: "
                                f"its deepest point is at {float(x[centre])!r} mm "
                                f"({rec.files[0]}, line {rec.lines[0][centre]})")
        centre = first + int(np.argmin(smooth[first:last + 1]))
        return first, centre, last
    margin = int(math.ceil(WINDOW_MARGIN_MM / rec.spacing_mm))
    lo = hi = centre
    while lo - centre > -n // 4 and smooth[(lo - 1) % n] < -EDGE_FRACTION * depth:
        lo -= 1
    while hi - centre < n // 4 and smooth[(hi + 1) % n] < -EDGE_FRACTION * depth:
        hi += 1
    return lo - margin, centre, hi + margin


def split(rec: Records, wheel_radius: float = 0.45, window_mm=None,
          contact_half_width_mm: float = 7.0, taper_mm: float = 10.0) -> MeasuredFlat:
    """Split a measurement into its 3D flat and the wheel's out-of-roundness (module rules).

    Args:
        rec: the records (:func:`wfjax.sections.read_records`).
        wheel_radius: R [m].
        window_mm: (start, end) record positions [mm] of the flat's window; None: located.
        contact_half_width_mm: lines within +- this [mm] of y = 0 enter the out-of-roundness.
        taper_mm: raised-cosine taper [mm] of the out-of-roundness outside the window.

    Returns:
        :class:`MeasuredFlat`.
    """
    first, centre, last = locate_window(rec, window_mm)
    n = rec.position_mm.size
    dx = rec.spacing_mm
    idx = np.arange(first, last + 1)
    dev = rec.deviation_um
    k = BACKGROUND_SAMPLES
    left = dev[:, np.arange(first - k, first) % n].mean(axis=1)
    right = dev[:, np.arange(last + 1, last + 1 + k) % n].mean(axis=1)
    t = (idx - first) / max(last - first, 1)
    background = left[:, None] * (1 - t) + right[:, None] * t
    z = -(dev[:, idx % n] - background) * 1e-6
    x = (idx - centre) * dx * 1e-3
    try:
        flat = Flat.from_sections(x, rec.lateral_mm * 1e-3, z, wheel_radius=wheel_radius)
    except ValueError as exc:
        raise SectionsError(f"{rec.files[0]}: {exc}") from None
    rough = _out_of_roundness(rec, first, centre, last, contact_half_width_mm, taper_mm)
    window = (float(rec.position_mm[first % n]), float(rec.position_mm[last % n]))
    return MeasuredFlat(flat, rough, window, float(rec.position_mm[centre % n]))


def _out_of_roundness(rec: Records, first, centre, last, half_width, taper) -> Roughness:
    n = rec.position_mm.size
    dx = rec.spacing_mm
    y = rec.lateral_mm
    near = np.abs(y) <= half_width
    if not near.any():
        near = np.abs(y) == np.min(np.abs(y))
    mean = rec.deviation_um[near].mean(axis=0) * 1e-6
    # distance [mm] of each sample outside the window (0 inside), periodic
    i = np.arange(n)
    before = (first - i) % n
    after = (i - last) % n
    inside = ((i - first) % n) <= (last - first)
    dist = np.where(inside, 0.0, np.minimum(before, after) * dx)
    weight = np.where(dist >= taper, 1.0, 0.5 * (1 - np.cos(np.pi * np.clip(dist / taper, 0,
                                                                              1))))
    values = (mean - mean[~inside].mean()) * weight
    return Roughness(x_start=0.0, spacing=dx * 1e-3, values=np.roll(values, -(centre % n)),
                     periodic=True)


def from_values(values: dict) -> MeasuredFlat:
    """:func:`split` of a case's ``flat.sections`` records (``values``: the case's
    ``{"section.key": value}``, lists or ``"a,b,c"`` strings of mm)."""
    from ..options import parse_number_list
    from ..sections import read_records

    def numbers(value):
        return parse_number_list(value) if isinstance(value, str) else list(
            np.atleast_1d(np.asarray(value, dtype=float)))

    if not values.get("flat.sections") or values.get("flat.section_positions_mm") is None:
        raise SectionsError('flat.kind = "sections" needs flat.sections and '
                            "flat.section_positions_mm (--sections DIR_OR_CSV "
                            "--section-positions-mm=...)")
    window = values.get("flat.section_window_mm")
    if window is not None and len(numbers(window)) != 2:
        raise SectionsError(f"flat.section_window_mm = {window!r}: give two positions, "
                            "start,end [mm]")
    radius = float(values["wheel.radius"])
    rec = read_records(values["flat.sections"], numbers(values["flat.section_positions_mm"]),
                       radius)
    return split(rec, radius, window_mm=None if window is None else numbers(window))


def case_wheel_roughness(case, wheel_rough):
    """The wheel roughness of a command's case: ``wheel_rough`` (``roughness.wheel_csv``)
    when given, else the out-of-roundness of a ``flat.sections`` measurement, else None."""
    if wheel_rough is not None or case.get("flat.kind") != "sections":
        return wheel_rough
    return from_values(case.values).wheel_roughness

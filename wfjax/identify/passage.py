"""Passages of a train over a wheel impact load detector: the CSV format, its reader (with the
bad-input checks) and writer.

One row per wheel and passage. Columns (units in the names):

=====================  ==================================================================
``passage``            passage number (integer; several passages may see the same wheel)
``wheel``              wheel number, 0 = the leading wheel, consecutive from 0 in a passage
``position_m``         the wheel's distance behind the leading wheel [m] (the layout)
``speed_kmh``          train speed of the passage [km/h], 5-300, the same for every row
``gauge_offset_m``     shear bridges' distance from the sleeper centres [m]
``calibration``        factor on the shear difference (``wfjax.Detector``)
``reading_bay<k>_kN``  the wheel's reading in instrumented bay k [kN] (bay k spans
                       [k L_S, (k + 1) L_S), consecutive k), one column per bay; or
``peak_kN``            only the wheel's peak reading over the bays [kN]
=====================  ==================================================================
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
import re

import numpy as np

from .. import limits
from ..scenario.sensors import Detector

__all__ = ["Passage", "PassageError", "read_passages", "passages_csv", "check_layout",
           "MAX_READING_KN", "SPEED_RANGE_KMH"]

MAX_READING_KN = 3000.0  # above this a reading is taken to be in N, not kN
MIN_READING_KN = 1.0
SPEED_RANGE_KMH = (5.0, 300.0)
FIXED = ("passage", "wheel", "position_m", "speed_kmh", "gauge_offset_m", "calibration")
BAY = re.compile(r"^reading_bay(-?\d+)_kN$")


class PassageError(ValueError):
    """A bad readings file: one line naming the row, column or value and what is allowed."""


@dataclasses.dataclass(frozen=True)
class Passage:
    """One passage of a train over the detector.

    Attributes:
        speed: v [m/s]. positions: [n_wheels] distance behind the leading wheel [m].
        bays: [n_bays] instrumented bay indices k (consecutive), or None with peaks only.
        readings: [n_wheels, n_bays] N (or [n_wheels, 1] peak readings).
        gauge_offset: [m]; calibration: factor (:class:`wfjax.Detector`).
        first_bay: the detector's first bay when ``bays`` is None (peak-only files; -1).
    """

    speed: float
    positions: np.ndarray
    bays: np.ndarray | None
    readings: np.ndarray
    gauge_offset: float = 0.1
    calibration: float = 1.0
    n_detector_bays: int = 3
    first_bay: int = -1

    @property
    def peak_only(self) -> bool:
        return self.bays is None

    @property
    def n_wheels(self) -> int:
        return int(np.size(self.positions))

    def detector(self) -> Detector:
        """The :class:`Detector` of the passage."""
        if self.bays is None:
            return Detector(self.n_detector_bays, self.first_bay, self.gauge_offset,
                            self.calibration)
        return Detector(int(self.bays.size), int(self.bays[0]), self.gauge_offset,
                        self.calibration)

    def detector_bays(self) -> np.ndarray:
        """[n_bays] the detector's bay indices."""
        return self.detector().bays()


def _number(text: str, row: int, column: str, path: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise PassageError(f"{path}: row {row}, column {column}: value {text!r} is not a "
                           "number") from None
    if not math.isfinite(value):
        raise PassageError(f"{path}: row {row}, column {column}: value {text!r} is not finite; "
                           "allowed: a finite number")
    return value


def _check_header(header: list[str], path: str) -> list[int] | None:
    missing = [c for c in FIXED if c not in header]
    if missing:
        raise PassageError(f"{path}: missing column {missing[0]!r}; the columns are "
                           f"{', '.join(FIXED)}, then reading_bay<k>_kN per bay or peak_kN")
    bays = [int(BAY.match(c).group(1)) for c in header if BAY.match(c)]
    if not bays:
        if "peak_kN" not in header:
            raise PassageError(f"{path}: no readings: give columns reading_bay<k>_kN (one per "
                               "bay, k the bay index) or peak_kN")
        return None
    if sorted(bays) != list(range(min(bays), min(bays) + len(bays))):
        gap = next(k for k in range(min(bays), max(bays) + 1) if k not in bays)
        raise PassageError(f"{path}: missing bay column reading_bay{gap}_kN; allowed: "
                           "consecutive bays")
    return sorted(bays)


def _reading(text: str, row: int, column: str, path: str) -> float:
    if text.strip() == "":
        raise PassageError(f"{path}: row {row}, column {column}: missing reading; allowed: a "
                           "reading in kN for every wheel and bay")
    value = _number(text, row, column, path)
    if value > MAX_READING_KN:
        raise PassageError(f"{path}: row {row}, column {column}: value {text} kN is above "
                           f"{MAX_READING_KN:g} kN: readings in N, not kN (off by 1000)? "
                           f"allowed: ({MIN_READING_KN:g}, {MAX_READING_KN:g}] kN")
    if value < MIN_READING_KN:
        raise PassageError(f"{path}: row {row}, column {column}: value {text} kN; allowed: "
                           f"({MIN_READING_KN:g}, {MAX_READING_KN:g}] kN")
    return value * 1e3


def _rows(text: str, path: str) -> tuple[list[str], list[tuple[int, dict]]]:
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    reader = csv.reader(lines)
    header = [h.strip() for h in next(reader, [])]
    if not header:
        raise PassageError(f"{path}: empty file; allowed: a header and one row per wheel")
    rows = []
    for i, cells in enumerate(reader, start=2):
        if len(cells) != len(header):
            raise PassageError(f"{path}: row {i}: {len(cells)} values for {len(header)} "
                               "columns")
        rows.append((i, dict(zip(header, (c.strip() for c in cells), strict=True))))
    if not rows:
        raise PassageError(f"{path}: no rows; allowed: one row per wheel and passage")
    return header, rows


def _passage(rows, bays, path: str) -> Passage:
    """One passage from its rows (already sorted by wheel)."""
    first, cells = rows[0]
    speed = _number(cells["speed_kmh"], first, "speed_kmh", path)
    lo, hi = SPEED_RANGE_KMH
    if not lo <= speed <= hi:
        raise PassageError(f"{path}: row {first}, column speed_kmh: value {cells['speed_kmh']} "
                           f"km/h out of range; allowed: [{lo:g}, {hi:g}] km/h")
    wheels = [int(_number(c["wheel"], i, "wheel", path)) for i, c in rows]
    for expect, (w, (i, _)) in enumerate(zip(wheels, rows, strict=True)):
        if w != expect:
            raise PassageError(f"{path}: row {i}, column wheel: value {w}: wheel {expect} is "
                               f"missing; allowed: wheels 0..n-1, one row each")
    for i, c in rows:
        if _number(c["speed_kmh"], i, "speed_kmh", path) != speed:
            raise PassageError(f"{path}: row {i}, column speed_kmh: value {c['speed_kmh']}: "
                               f"allowed: one speed per passage ({cells['speed_kmh']})")
    pos = np.array([_number(c["position_m"], i, "position_m", path) for i, c in rows])
    if pos[0] != 0 or np.any(np.diff(pos) <= 0):
        bad = rows[0] if pos[0] != 0 else rows[int(np.argmin(np.diff(pos))) + 1]
        raise PassageError(f"{path}: row {bad[0]}, column position_m: value "
                           f"{bad[1]['position_m']}; allowed: 0 for wheel 0, then increasing")
    cols = ["peak_kN"] if bays is None else [f"reading_bay{k}_kN" for k in bays]
    reads = np.array([[_reading(c[col], i, col, path) for col in cols] for i, c in rows])
    g = _number(cells["gauge_offset_m"], first, "gauge_offset_m", path)
    cal = _number(cells["calibration"], first, "calibration", path)
    try:
        det = Detector(len(bays) if bays else 3, bays[0] if bays else -1, g, cal)
    except ValueError as exc:
        raise PassageError(f"{path}: row {first}: {exc}") from None
    return Passage(speed / 3.6, pos, None if bays is None else np.asarray(bays), reads,
                   det.gauge_offset, det.calibration)


def read_passages(path, text: str | None = None) -> list[Passage]:
    """The passages of the readings CSV at ``path`` (or its ``text``).

    Raises:
        PassageError: one line naming the row, column or value and what is allowed.
    """
    name = str(path)
    if text is None:
        text = limits.read_text(path, f"--readings {name}")
    header, rows = _rows(text, name)
    bays = _check_header(header, name)
    groups: dict[int, list] = {}
    for i, c in rows:
        groups.setdefault(int(_number(c["passage"], i, "passage", name)), []).append((i, c))
    out = []
    for _, grp in sorted(groups.items()):
        grp.sort(key=lambda r: _number(r[1]["wheel"], r[0], "wheel", name))
        out.append(_passage(grp, bays, name))
    n = {p.n_wheels for p in out}
    if len(n) > 1:
        raise PassageError(f"{name}: passages read {sorted(n)} wheels; allowed: the same "
                           "train (the same number of wheels) in every passage")
    return out


def check_layout(passages: list[Passage], positions) -> None:
    """PassageError unless every passage's wheel positions equal ``positions`` [m] (a
    vehicle preset's or case's layout) within 1 cm."""
    positions = np.asarray(positions, float)
    for p in passages:
        if p.n_wheels != positions.size:
            raise PassageError(f"layout: {positions.size} wheels, but the readings have "
                               f"{p.n_wheels}; allowed: a layout with one wheel per row")
        bad = np.flatnonzero(np.abs(p.positions - positions) > 0.01)
        if bad.size:
            i = int(bad[0])
            raise PassageError(f"layout: wheel {i} at {positions[i]:g} m, but the readings put "
                               f"it at {p.positions[i]:g} m; allowed: within 0.01 m")


def passages_csv(passages: list[Passage]) -> str:
    """The CSV text of ``passages`` (all with bays, or all peak-only)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    bays = passages[0].bays
    cols = ["peak_kN"] if bays is None else [f"reading_bay{int(k)}_kN" for k in bays]
    w.writerow(list(FIXED) + cols)
    for n, p in enumerate(passages):
        for i in range(p.n_wheels):
            w.writerow([n, i, f"{p.positions[i]:.4f}", f"{p.speed * 3.6:.6g}",
                        f"{p.gauge_offset:g}", f"{p.calibration:g}"]
                       + [f"{r / 1e3:.4f}" for r in p.readings[i]])
    return buf.getvalue()

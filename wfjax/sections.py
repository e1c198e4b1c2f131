"""Reading and writing a wheel-roughness gauge's records: radial deviation along the whole
circumference at several lateral lines across the tread (docs/measured_flats.md).

Layouts:

* a directory, one text file per lateral line (files in name order, hidden files skipped),
  each two columns: position [mm] and deviation [um];
* one CSV, a column per line: position [mm], then one deviation column [um] per line.

Text: UTF-8 (a byte-order mark dropped) or, failing that, Latin-1; any header lines before
the first row of numbers; ``#`` lines are comments. Separators: ``;``, tab or blanks, in which
case a comma inside a number is its decimal point (``12,5``); otherwise ``,`` separates and
the decimal point is a point. Deviation is the radius's, positive outward (a flat is a dip).

Checks (:class:`SectionsError`, a ``ValueError``: one line naming the file, the line and the
value, which the command line turns into exit status 2 before anything is written): numbers
only after the header, positions strictly increasing and uniformly spaced (within 0.1 % of
the spacing), every record of the same start, spacing and length, |deviation| <= 5 mm, lateral
positions strictly increasing and one per record, and a record that closes around the
circumference: n x spacing = 2 pi R within half a spacing.

The numbers are kept as read (mm and um floats), so writing them back (:func:`write_records`,
``repr`` digits) and reading again round-trips every value to the last digit.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from pathlib import Path

import numpy as np

from . import limits

__all__ = ["SectionsError", "Records", "read_records", "write_records", "MAX_DEVIATION_UM"]

MAX_DEVIATION_UM = 5000.0  # the model's deepest flat, 5 mm
SPACING_TOLERANCE = 1e-3  # relative deviation of a record's steps from its mean spacing


class SectionsError(ValueError):
    """A record that cannot be read: one line naming the file, the line and the value."""


@dataclasses.dataclass(frozen=True)
class Records:
    """Records of one measurement, as read.

    Attributes:
        position_mm: [n] positions along the circumference [mm], uniformly spaced.
        deviation_um: [k, n] radial deviation [um] of each lateral line (positive outward).
        lateral_mm: [k] lateral positions [mm], strictly increasing (0: the nominal contact
            line on the rail head's crown).
        files: [k] the file each record came from (the same CSV for every column).
        lines: [k, n] the line number of each sample in its file (1-based).
    """

    position_mm: np.ndarray
    deviation_um: np.ndarray
    lateral_mm: np.ndarray
    files: tuple
    lines: np.ndarray

    @property
    def spacing_mm(self) -> float:
        """The sample spacing [mm]."""
        return float((self.position_mm[-1] - self.position_mm[0]) / (len(self.position_mm) - 1))


def _decode(path) -> str:
    data = limits.read_bytes(path, str(path))
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def _split(line: str) -> list[str]:
    """Fields of a data line (module docstring: separators and decimal commas)."""
    text = line.strip()
    if ";" in text or "\t" in text:
        fields = re.split(r"\s*[;\t]\s*", text)
    elif re.search(r"\s", text):
        fields = text.split()
    else:
        return [f.strip() for f in text.split(",")]
    return [f.replace(",", ".") for f in fields]


def _numbers(fields: list[str]) -> list[float] | None:
    try:
        return [float(f) for f in fields]
    except ValueError:
        return None


def _parse(path, n_columns: int | None) -> tuple[np.ndarray, np.ndarray]:
    """Rows of numbers of a file after its header: ([m, c] values, [m] line numbers)."""
    rows, lines, started = [], [], False
    for i, raw in enumerate(_decode(path).splitlines(), start=1):
        if not raw.strip() or raw.lstrip().startswith("#"):
            continue
        fields = _split(raw)
        values = _numbers(fields)
        if not started and (values is None or len(values) < 2):
            continue  # header
        started = True
        if values is None:
            raise SectionsError(f"{path}: line {i}: not a number: {raw.strip()!r}")
        width = n_columns or len(rows[0]) if rows else (n_columns or len(values))
        if len(values) != width:
            raise SectionsError(f"{path}: line {i}: {len(values)} fields, need {width}: "
                                f"{raw.strip()!r}")
        bad = [v for v in values if not math.isfinite(v)]
        if bad:
            raise SectionsError(f"{path}: line {i}: not finite: {float(bad[0])!r}")
        rows.append(values)
        lines.append(i)
    if len(rows) < 3:
        raise SectionsError(f"{path}: {len(rows)} rows of numbers after the header; need at "
                            "least 3 (position mm, deviation um)")
    return np.asarray(rows, dtype=float), np.asarray(lines)


def _check_positions(path, x, lines) -> None:
    step = np.diff(x)
    bad = np.flatnonzero(step <= 0)
    if bad.size:
        i = bad[0] + 1
        raise SectionsError(f"{path}: line {lines[i]}: position {float(x[i])!r} mm does not "
                            f"increase (after {float(x[i - 1])!r} mm)")
    mean = (x[-1] - x[0]) / (len(x) - 1)
    bad = np.flatnonzero(np.abs(step - mean) > SPACING_TOLERANCE * mean)
    if bad.size:
        i = bad[0] + 1
        raise SectionsError(f"{path}: line {lines[i]}: position {float(x[i])!r} mm is not on the "
                            f"uniform spacing {mean:.6g} mm (resample the record)")


def _files(source: Path) -> list[Path]:
    if source.is_dir():
        files = sorted(p for p in source.iterdir() if p.is_file() and not p.name.startswith("."))
        if not files:
            raise SectionsError(f"{source}: no record files in the directory")
        return files
    return [source]


def read_records(source, lateral_mm, wheel_radius: float = 0.45) -> Records:
    """Read a measurement: a directory of one-line files or one CSV with a column per line.

    Args:
        source: the directory or the CSV file.
        lateral_mm: [k] lateral position of each record [mm], strictly increasing.
        wheel_radius: R [m]; each record must cover one circumference.

    Returns:
        :class:`Records`.

    Raises:
        SectionsError: one line naming the file, the line and the value.
    """
    source = Path(source)
    lateral = np.atleast_1d(np.asarray(lateral_mm, dtype=float))
    files = _files(source)
    xs, devs, names, nums = [], [], [], []
    for path in files:
        rows, lines = _parse(path, None if len(files) == 1 else 2)
        if len(files) > 1 and rows.shape[1] != 2:
            raise SectionsError(f"{path}: line {lines[0]}: {rows.shape[1]} columns; a file "
                                "per line has two: position mm, deviation um")
        for col in range(1, rows.shape[1]):
            xs.append(rows[:, 0])
            devs.append(rows[:, col])
            names.append(str(path))
            nums.append(lines)
    _check_consistent(xs, names, nums, lateral, source)
    dev = np.asarray(devs)
    for j, d in enumerate(dev):
        bad = np.flatnonzero(np.abs(d) > MAX_DEVIATION_UM)
        if bad.size:
            i = bad[0]
            raise SectionsError(f"{names[j]}: line {nums[j][i]}: deviation {float(d[i])!r} um "
                                f"beyond +-{MAX_DEVIATION_UM:g} um (5 mm; values in nm or mm?)")
    rec = Records(xs[0], dev, lateral, tuple(names), np.asarray(nums))
    _check_closes(rec, wheel_radius)
    return rec


def _check_consistent(xs, names, nums, lateral, source) -> None:
    _check_positions(names[0], xs[0], nums[0])
    for x, name, lines in zip(xs[1:], names[1:], nums[1:], strict=True):
        _check_positions(name, x, lines)
        if len(x) != len(xs[0]):
            raise SectionsError(f"{name}: line {lines[-1]}: {len(x)} samples, the first "
                                f"record ({names[0]}) has {len(xs[0])}: records of different "
                                "lengths")
        diff = np.flatnonzero(x != xs[0])
        if diff.size:
            i = diff[0]
            raise SectionsError(f"{name}: line {lines[i]}: position {float(x[i])!r} mm, the first "
                                f"record has {float(xs[0][i])!r} mm: different starts or spacings")
    if len(lateral) != len(xs):
        raise SectionsError(f"{source}: {len(xs)} records but {len(lateral)} lateral positions "
                            "(--section-positions-mm)")
    bad = np.flatnonzero(np.diff(lateral) <= 0)
    if bad.size:
        i = bad[0] + 1
        raise SectionsError(f"--section-positions-mm: value {i + 1} ({float(lateral[i])!r} mm, "
                            f"{names[i]}) does not increase after {float(lateral[i - 1])!r} mm")


def _check_closes(rec: Records, wheel_radius: float) -> None:
    dx = rec.spacing_mm
    span = len(rec.position_mm) * dx
    circ = 2 * math.pi * float(wheel_radius) * 1e3
    if abs(span - circ) > dx / 2:
        raise SectionsError(
            f"{rec.files[0]}: line {rec.lines[0][-1]}: the record ends at "
            f"{rec.position_mm[-1]!r} mm: {len(rec.position_mm)} samples x {dx:.6g} mm = "
            f"{span:.6g} mm, not the circumference 2 pi R = {circ:.6g} mm (within half a "
            "spacing): the record does not close")


def write_records(rec: Records, target, one_csv: bool = True, decimal: str = ".") -> list[Path]:
    """Write ``rec`` as one CSV (``target`` a file) or a file per line (``target`` a
    directory, files ``line_01.csv``, ...), values as ``repr`` digits; ``decimal=","`` writes
    decimal commas with ``;`` separators. Returns the files written."""
    sep = ";" if decimal == "," else ","

    def fmt(v):
        text = repr(float(v))
        return text.replace(".", ",") if decimal == "," else text

    target = Path(target)
    header = "# wfjax sections: position [mm], deviation [um], lateral positions [mm]: "
    header += " ".join(fmt(v) for v in rec.lateral_mm) + "\n"
    if one_csv:
        cols = sep.join(["position_mm"] + [f"line_{j + 1}_um" for j in range(len(rec.files))])
        body = [sep.join(fmt(v) for v in (x, *d))
                for x, d in zip(rec.position_mm, rec.deviation_um.T, strict=True)]
        target.write_text(header + cols + "\n" + "\n".join(body) + "\n", encoding="utf-8")
        return [target]
    os.makedirs(target, exist_ok=True)
    out = []
    for j, d in enumerate(rec.deviation_um):
        path = target / f"line_{j + 1:02d}.csv"
        body = [f"{fmt(x)}{sep}{fmt(v)}" for x, v in zip(rec.position_mm, d, strict=True)]
        path.write_text(header + f"position_mm{sep}deviation_um\n" + "\n".join(body) + "\n",
                        encoding="utf-8")
        out.append(path)
    return out

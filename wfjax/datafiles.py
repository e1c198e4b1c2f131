"""The data files a case names: a measured flat profile's CSV (:func:`read_profile_csv`) and
the sha256 of any input file for the provenance (:func:`file_sha256`)."""

from __future__ import annotations

import csv
import hashlib
import io
import math
import os

import numpy as np

from . import limits
from . import params as P
from .options import CaseError

__all__ = ["read_profile_csv", "file_sha256", "check_recorded_inputs", "PROFILE_STEP"]

PROFILE_STEP = 0.1e-3  # m; measured profiles are resampled on this uniform grid
PROFILE_COLUMNS = ("x_mm", "z_mm")


def read_profile_csv(path: str | os.PathLike, smoothing_mm: float = 0.0):
    """A measured flat profile from CSV, as (x [m], z [m]) for :meth:`Flat.from_profile`.

    Columns ``x_mm`` (circumferential coordinate [mm], strictly increasing, any origin) and
    ``z_mm`` (radial deviation [mm]: depth of material missing from the round wheel, >= 0,
    zero on the undamaged surface). Steps: checks (at least 5 rows, numbers, finite,
    increasing x, no negative z beyond 0.02 mm of noise, both ends back on the undamaged
    surface within 5 % of the depth, depth <= 5 mm); negative noise clipped to 0; linear
    resampling on a uniform 0.1 mm grid; optional Gaussian smoothing (standard deviation
    ``smoothing_mm`` on a grid widened by 4 standard deviations on each side, so the missing
    area is kept; the ends held at 0); centring on the centroid of the missing area.

    Raises:
        CaseError: one line naming the file, the line or column and what is wrong.
    """

    source = str(path)
    try:
        text = limits.read_text(path, f"--profile-csv {source}")
    except limits.InputError as exc:
        raise CaseError(str(exc)) from None
    rows = [r for r in csv.reader(io.StringIO(text)) if r and any(c.strip() for c in r)]
    rows = [r for r in rows if not r[0].lstrip().startswith("#")]
    if not rows:
        raise CaseError(f"{source}: empty profile file; need columns x_mm,z_mm")
    header = [c.strip() for c in rows[0]]
    if header != list(PROFILE_COLUMNS):
        hint = (" (lengths must be in mm: multiply by 1000 and rename)"
                if header in (["x_m", "z_m"], ["x", "z"]) else "")
        raise CaseError(f"{source}: header must be x_mm,z_mm (circumferential coordinate and "
                        f"radial deviation in mm), got {','.join(header)}{hint}")
    values = []
    for i, row in enumerate(rows[1:], start=2):
        if len(row) != 2:
            raise CaseError(f"{source}: line {i} has {len(row)} fields, need 2 (x_mm,z_mm)")
        try:
            pair = [float(c) for c in row]
        except ValueError:
            raise CaseError(f"{source}: line {i}: not a number: {','.join(row)}") from None
        if not all(math.isfinite(v) for v in pair):
            raise CaseError(f"{source}: line {i}: NaN or infinite value")
        values.append(pair)
    if len(values) < 5:
        raise CaseError(f"{source}: need at least 5 rows of x_mm,z_mm, got {len(values)}")
    x, z = np.asarray(values).T
    bad = np.flatnonzero(np.diff(x) <= 0)
    if bad.size:
        raise CaseError(f"{source}: x_mm must be strictly increasing; line {bad[0] + 3} "
                        f"({x[bad[0] + 1]:g}) follows {x[bad[0]]:g}")
    depth = float(z.max())
    if z.min() < -0.02:
        hint = (" (z is material removed, positive into the wheel: flip the sign?)"
                if depth <= 0.02 else "")
        raise CaseError(f"{source}: z_mm down to {z.min():g} mm; allowed: >= -0.02 mm of "
                        f"measurement noise{hint}")
    if depth <= 0:
        raise CaseError(f"{source}: z_mm is nowhere > 0: no flat in the profile")
    if depth > P.MAX_FLAT_DEPTH * 1e3:
        raise CaseError(f"{source}: z_mm maximum {depth:g} mm; allowed: (0, "
                        f"{P.MAX_FLAT_DEPTH * 1e3:g}] mm (values in um instead of mm?)")
    for end, value in (("first", z[0]), ("last", z[-1])):
        if value > 0.05 * depth:
            raise CaseError(f"{source}: the {end} row has z_mm = {value:g} mm, {value / depth:.0%}"
                            " of the depth; the profile must reach the undamaged surface (z "
                            "within 5 % of the depth of 0) at both ends: extend it")
    if not 0 <= smoothing_mm <= 20:
        raise CaseError(f"flat.profile_smoothing_mm = {smoothing_mm!r}: out of range; "
                        "allowed: [0, 20] mm")
    z = np.maximum(z, 0.0)
    step = PROFILE_STEP * 1e3
    n = int(np.floor((x[-1] - x[0]) / step)) + 1
    xu = x[0] + step * np.arange(n)
    zu = np.interp(xu, x, z)
    zu[0] = zu[-1] = 0.0
    if smoothing_mm > 0:
        xu, zu = _smooth(xu, zu, smoothing_mm, step)
    centre = float(np.sum(xu * zu) / np.sum(zu))
    return (xu - centre) * 1e-3, zu * 1e-3


def _smooth(xu: np.ndarray, zu: np.ndarray, sigma_mm: float, step_mm: float):
    """Gaussian smoothing (standard deviation ``sigma_mm``) of the profile ``zu`` [mm] on the
    uniform grid ``xu`` [mm] (spacing ``step_mm``), keeping its area: the grid is widened by
    4 sigma on each side, so the material the kernel spreads past the measured ends stays in
    the profile (the widened ends are held at 0; they carry < 0.01 % of the area)."""
    half = int(np.ceil(4 * sigma_mm / step_mm))
    kernel = np.exp(-0.5 * (np.arange(-half, half + 1) * step_mm / sigma_mm) ** 2)
    zs = np.convolve(zu, kernel / kernel.sum(), mode="full")
    xs = xu[0] + step_mm * np.arange(-half, xu.size + half)
    zs[0] = zs[-1] = 0.0
    return xs, zs


def file_sha256(path) -> str:
    """sha256 of a file's bytes (recorded in provenance for data and profiles)."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def check_recorded_inputs(summary: dict, source: str) -> None:
    """Refuse a rerun from a JSON summary whose input files changed since: every file the
    summary's provenance records a sha256 of must still have that sha256."""
    recorded = (summary.get("provenance") or {}).get("inputs_sha256") or {}
    if not isinstance(recorded, dict):
        return
    for name, digest in recorded.items():
        if not os.path.exists(name):
            continue
        try:
            now = file_sha256(name)
        except (OSError, ValueError):
            continue
        if now != digest:
            raise CaseError(f"{source}: input file {name} changed since the run (sha256 "
                            f"{now[:12]}..., recorded {str(digest)[:12]}...); the rerun would "
                            "not repeat it: restore the file or write a new case")

"""The identification's prediction from a response table: the readings of one wheel in a
detector's bays for every shape, length and impact coordinate (phase) over a wheel
circumference, every strike of the flat included (:func:`predict`), and its peak contact
forces (:func:`predict_peak`). The table itself, and the coupled runs, are
:mod:`wfjax.identify.forward`'s.
"""

from __future__ import annotations

import math

import numpy as np

from .forward import ResponseTable

__all__ = ["phase_grid", "predict", "predict_refined", "predict_peak"]


def phase_grid(table: ResponseTable, bays: np.ndarray, refine: int = 1) -> np.ndarray:
    """[P] impact rail coordinates x [m] (x = 0: the sleeper at the start of bay 0), the
    table's in-bay positions (``refine`` points per table interval) over one wheel
    circumference 2 pi R from the start of the detector's first bay ``bays[0]``: a flat
    strikes once in every circumference, so exactly one of its strikes lies there; the others,
    2 pi R apart, follow from it (:func:`predict`)."""
    ls, j = table.sleeper_spacing, table.offsets.size
    circumference = 2 * math.pi * table.wheel_radius
    x0 = int(bays[0]) * ls
    n = int(round(circumference / (ls / j))) * int(refine)
    return x0 + np.arange(n) * ls / (j * int(refine))


def predict_refined(table: ResponseTable, bays, lengths, refine: int) -> np.ndarray:
    """:func:`predict` on ``phase_grid(table, bays, refine)``: between the table's impact
    positions the readings are interpolated linearly in the position (a gate edge between
    two positions becomes a ramp, not a step that the grid cannot place)."""
    step = table.sleeper_spacing / table.offsets.size
    native = phase_grid(table, bays)
    coarse = predict(table, bays, lengths, np.append(native, native[-1] + step))
    fine = phase_grid(table, bays, refine)
    w = (fine - native[0]) / step
    i0 = np.minimum(np.floor(w + 1e-9).astype(int), native.size - 1)
    f = (w - i0)[None, None, :, None, None]
    return coarse[:, :, i0] * (1 - f) + coarse[:, :, i0 + 1] * f


def predict(table: ResponseTable, bays, lengths, phases) -> np.ndarray:
    """Readings [S, n_len, P, R, n_bays] N of one wheel in detector ``bays`` (absolute bay
    indices) for every shape, ``lengths`` [n_len] m (linear interpolation in the table's
    lengths, clamped) and impact coordinate ``phases`` [P] m on :func:`phase_grid`.

    Every strike: the flat strikes at x + k 2 pi R for every integer k. A bay reads the
    table at the last strike at or before it (its in-bay position and the bay offset
    from it, 0..TABLE_BAYS - 1 (:data:`wfjax.identify.forward.TABLE_BAYS`): a circumference
    is less than ``TABLE_BAYS`` bays, so the
    last strike is never farther back; a bay farther reads the table's shortest flat, as good
    as round there). The strike before that one, more than a circumference back, is left out:
    against runs with every strike, this rule reads within 0.7 % (docs/identify.md, "Every
    strike"). A strike between two table positions reads the nearest; with the default 20
    positions per bay a 0.45 m wheel's circumference is 87.0 positions (0.1 mm off), so
    every strike of a phase on :func:`phase_grid` lies on one."""
    phases, bays = np.asarray(phases, float), np.asarray(bays, int)
    ls, nj = table.sleeper_spacing, table.offsets.size
    circumference = 2 * math.pi * table.wheel_radius
    n_back = int(math.ceil((bays.max() - bays.min() + 1) * ls / circumference)) + 1
    k = np.arange(-n_back, n_back + 1)
    idx = np.round((phases[:, None] + k[None, :] * circumference) / (ls / nj)).astype(int)
    q, j = np.floor_divide(idx, nj), np.mod(idx, nj)  # [P, K] each strike's bay and position
    before = q[:, None, :] <= bays[None, :, None]  # [P, n_bays, K]
    last = np.argmax(np.where(before, q[:, None, :], np.iinfo(int).min), axis=-1)
    q_last, j_last = (np.take_along_axis(a, last, axis=1) for a in (q, j))
    rel = bays[None, :] - q_last  # [P, n_bays], >= 0
    t = table.readings  # [S, L, J, R, TABLE_BAYS]
    m = np.minimum(rel, t.shape[-1] - 1)
    far = (rel >= t.shape[-1])[:, :, None, None, None]
    vals = np.where(far, t[:, :1, j_last, :, m], t[:, :, j_last, :, m])  # [P, n_bays, S, L, R]
    vals = np.moveaxis(vals, (0, 1), (3, 4))  # [S, L, R, P, n_bays]
    w, i0 = _interp_weights(table.lengths, lengths)
    out = vals[:, i0] * (1 - w)[None, :, None, None, None] + \
        vals[:, i0 + 1] * w[None, :, None, None, None]
    return np.moveaxis(out, 2, 3)  # [S, n_len, P, R, n_bays]


def predict_peak(table: ResponseTable, lengths) -> np.ndarray:
    """Peak contact force [S, n_len, J, R] N at ``lengths`` [m] (interpolated, clamped)."""
    w, i0 = _interp_weights(table.lengths, lengths)
    p = table.peak
    return p[:, i0] * (1 - w)[None, :, None, None] + p[:, i0 + 1] * w[None, :, None, None]


def _interp_weights(grid: np.ndarray, x) -> tuple[np.ndarray, np.ndarray]:
    """(weights [n], lower indices [n]) of linear interpolation in ``grid``, clamped."""
    x = np.clip(np.asarray(x, float), grid[0], grid[-1])
    i0 = np.clip(np.searchsorted(grid, x, side="right") - 1, 0, grid.size - 2)
    return (x - grid[i0]) / (grid[i0 + 1] - grid[i0]), i0

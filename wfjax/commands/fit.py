"""``wfjax fit``: fit a flat's depth and length (or profile) to measured impact forces.

Data (``--data FILE.csv``, one header row, comma separated), one of:

* maximum force against speed (a wheel impact load detector): columns ``speed_kmh`` [km/h]
  and ``max_force_kN`` [kN]; at least 3 rows;
* a force time history at one speed (``--speed-kmh`` required): columns ``t_s`` [s, 0 when
  the flat centre is over the contact point] and ``force_kN`` [kN]; at least 10 rows.

``--example`` fits an embedded synthetic max-force dataset instead (rounded flat, depth
0.9 mm, length 100 mm, hertz-trajectory model, max over 3 impact positions, 3 % noise).

Writes ``fit.json`` (fitted parameters in mm with Gauss-Newton standard deviations and
convergence diagnostics), ``fit.csv`` (data and fitted forces), ``fit.png`` (data against fit)
and ``loss.png`` (loss curve) into ``--out``.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from .. import limits
from ..options import MAX_SPEED_KMH
from ._common import (
    case_vehicle,
    prepare_out,
    resolve_case,
    save_figure,
    write_atomic,
    write_summary,
)

HELP = ("fit a flat's geometry to measured max forces vs speed or a force history, on any "
        "vehicle, rough rail or supports (JSON, PNG)")

MAX_FORCE_COLUMNS = ("speed_kmh", "max_force_kN")
HISTORY_COLUMNS = ("t_s", "force_kN")
MAX_PLAUSIBLE_KN = 5000.0  # a larger "kN" value is almost surely in N
MIN_PLAUSIBLE_KN = 1.0  # a max force below 1 kN is in MN, or 1000 times too small
OUTLIER_FACTOR = 100.0  # a max force this far from the median is in another unit

EXAMPLE_CSV = """speed_kmh,max_force_kN
40.0,210.77
54.3,202.23
68.6,197.08
82.9,183.33
97.1,199.10
111.4,229.73
125.7,260.43
140.0,282.47
"""


def _read_columns(text: str, source: str) -> dict[str, np.ndarray]:
    """The numeric columns of CSV ``text`` by header name, plus ``"_line"``: the file line
    of every row (a leading UTF-8 byte-order mark, as Excel writes, is dropped)."""
    text = text.removeprefix("\ufeff")
    rows = [(i, r) for i, r in enumerate(csv.reader(io.StringIO(text)), start=1)
            if r and any(c.strip() for c in r)]
    if not rows:
        raise ValueError(f"{source}: empty file")
    header = [c.strip() for c in rows[0][1]]
    cols: dict[str, list[float]] = {h: [] for h in header}
    cols["_line"] = [i for i, _ in rows[1:]]
    for i, row in rows[1:]:
        if len(row) != len(header):
            raise ValueError(f"{source}: line {i} has {len(row)} fields, header has "
                             f"{len(header)}")
        for h, c in zip(header, row, strict=True):
            try:
                value = float(c)
            except ValueError:
                raise ValueError(f"{source}: line {i}, column {h}: not a number: {c!r}") from None
            if not math.isfinite(value):
                raise ValueError(f"{source}: line {i}, column {h}: NaN or infinite value")
            cols[h].append(value)
    return {h: np.asarray(v) for h, v in cols.items()}


def parse_data(text: str, source: str = "data", speed_kmh: float | None = None,
               impact_position_mm: float = 0.0):
    """Measured data in SI units from CSV text (see the module docstring for the columns).

    Returns:
        :class:`wfjax.fit.MaxForceData` or :class:`wfjax.fit.HistoryData`.
    """
    from ..fit import HistoryData, MaxForceData

    cols = _read_columns(text, source)
    if all(c in cols for c in MAX_FORCE_COLUMNS):
        v, f = cols["speed_kmh"], cols["max_force_kN"]
        _check_kn(f, "max_force_kN", source, cols["_line"])
        if np.any(v <= 0) or np.any(v > MAX_SPEED_KMH):
            raise ValueError(f"{source}: speed_kmh must be in (0, {MAX_SPEED_KMH:g}] km/h, got "
                             f"[{v.min():g}, {v.max():g}]")
        if v.size < 3:
            raise ValueError(f"{source}: need at least 3 rows of speed_kmh,max_force_kN, got "
                             f"{v.size}")
        return MaxForceData(v / 3.6, f * 1e3)
    if all(c in cols for c in HISTORY_COLUMNS):
        t, f = cols["t_s"], cols["force_kN"]
        _check_kn(f, "force_kN", source, cols["_line"], history=True)
        if speed_kmh is None:
            raise ValueError(f"{source}: a force history (t_s,force_kN) needs --speed-kmh")
        if np.ptp(t) > 5.0:
            raise ValueError(f"{source}: t_s spans {np.ptp(t):g} s; an impact lasts "
                             "milliseconds: are the times in ms instead of s?")
        if t.size < 10:
            raise ValueError(f"{source}: need at least 10 rows of t_s,force_kN, got {t.size}")
        return HistoryData(t, f * 1e3, speed_kmh / 3.6, impact_position_mm * 1e-3)
    hint = ""
    cols.pop("_line")
    if any(c.endswith("_N") for c in cols):
        hint = " (forces must be given in kN: rename and divide by 1000)"
    raise ValueError(f"{source}: need columns {','.join(MAX_FORCE_COLUMNS)} (max force vs "
                     f"speed) or {','.join(HISTORY_COLUMNS)} (time history); got "
                     f"{','.join(cols)}{hint}")


def _check_kn(force_kn: np.ndarray, name: str, source: str, lines=None,
              history: bool = False) -> None:
    """The plausibility rule of forces in kN (docs/case_files.md, "Measured data"): every
    value in [0, 5000] kN (above: in N), the largest at least 1 kN (below: in MN, or 1000x
    too small), and in max-force data every value at least 1 kN and within a factor 100 of
    the median (else one row in another unit). Raises ValueError naming the row's line."""
    if not force_kn.size:
        return
    lines = np.arange(2, force_kn.size + 2) if lines is None else np.asarray(lines)
    median = float(np.median(np.abs(force_kn)))
    if median > MAX_PLAUSIBLE_KN:
        raise ValueError(f"{source}: {name} values around {median:.3g} look like "
                         "N, not kN: divide by 1000")
    if float(np.max(force_kn)) < MIN_PLAUSIBLE_KN:
        raise ValueError(f"{source}: {name} values at most {np.max(force_kn):.3g} kN: a wheel's "
                         "contact force is tens to hundreds of kN; are they in MN (multiply "
                         "by 1000)?")
    low = MIN_PLAUSIBLE_KN if not history else -np.inf
    bad = (np.abs(force_kn) > MAX_PLAUSIBLE_KN) | (force_kn < low)
    if not history:
        bad |= (force_kn > OUTLIER_FACTOR * median) | (force_kn < median / OUTLIER_FACTOR)
    if np.any(bad):
        j = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{source}: line {int(lines[j])}: {name} = {force_kn[j]:g} does not "
                         f"fit the other rows (median {median:.4g} kN): a value in N, or a "
                         f"typo? allowed: [{MIN_PLAUSIBLE_KN:g}, {MAX_PLAUSIBLE_KN:g}] kN, within "
                         f"{OUTLIER_FACTOR:g}x of the median")


def _initial_flat(case):
    from ..fit import parametrisation_for

    flat = case.flat()
    n_basis = case["fit.profile_basis"]
    if flat.kind == "profile":
        return flat, parametrisation_for(flat, n_basis=n_basis or 8)
    if n_basis > 0:
        start = _profile_start(flat)
        return start, parametrisation_for(start, n_basis=n_basis)
    return flat, None


def _profile_start(flat):
    from ..model.geometry import profile_deviation
    from ..params import Flat

    half = 1.25 * flat.half_extent
    x = np.linspace(-half, half, 121)
    z = np.maximum(np.asarray(profile_deviation(flat, x)), 1e-7)
    return Flat.from_profile(x, z, float(flat.wheel_radius))


def run(args) -> int:
    case = resolve_case(args, "fit")
    if case["fit.example"]:
        text, source = EXAMPLE_CSV, "example"
    elif case.get("fit.data"):
        path = Path(case["fit.data"])
        text, source = limits.read_text(path, f"--data {path}"), str(path)
    else:
        raise ValueError("give --data FILE.csv or --example (or fit.data in the case file)")
    speed_kmh = case.get("run.speed_kmh")
    data = parse_data(text, source, speed_kmh, case["run.impact_position"] * 1e3)
    from .. import fit
    from ..fit.data import validate_data

    flat, par = _initial_flat(case)
    # The data must suffice for the parameters before any output or work (a measured
    # profile's 8 bump amplitudes need 9 speeds).
    validate_data(data, len((par or fit.parametrisation_for(flat)).names))
    wheel, track, material, config = case.model()
    track = case.supports(track)
    rail_rough, wheel_rough = case.roughness(float(wheel.radius))
    vehicle = case_vehicle(case, wheel)
    contact = case["run.contact"]
    out = prepare_out(args.out)
    if case["fit.example"]:
        write_atomic(out / "example_data.csv", EXAMPLE_CSV)
    print(f"fitting a {flat.kind} flat ({contact}, R_R = {float(track.rail_head_radius):g} m) "
          f"to {len(data[0])} points ...")

    def progress(i, loss, _flat):
        print(f"  iteration {i}: loss {loss:.4g}", flush=True)

    res = fit.fit_flat(data, flat, contact=contact, parametrisation=par,
                       impact_positions=case["run.impact_positions"],
                       temperature=case["fit.temperature_kN"] * 1e3 or None,
                       method=case["fit.method"], max_iter=case["fit.max_iter"],
                       wheel=wheel, track=track, material=material, config=config,
                       vehicle=vehicle, roughness=rail_rough, wheel_roughness=wheel_rough,
                       callback=progress)
    summary = res.summary()
    write_summary(out / "fit.json", summary, case,
                  {"data": case.get("fit.data"), "profile_csv": case.get("flat.profile_csv")})
    x_name = "speed_kmh" if res.kind == "max_force" else "t_s"
    x = res.x * 3.6 if res.kind == "max_force" else res.x
    rows = "".join(f"{a:.6g},{b / 1e3:.6f},{c / 1e3:.6f}\n"
                   for a, b, c in zip(x, res.measured, res.prediction, strict=True))
    write_atomic(out / "fit.csv", f"{x_name},measured_kN,fitted_kN\n" + rows)
    _figures(res, x, out)
    for name, value in res.params.items():
        print(f"{name}: {value * 1e3:.4f} +- {res.std[name] * 1e3:.4f} mm")
    print(f"residual rms {res.residual_rms / 1e3:.2f} kN; {res.n_iterations} iterations, "
          f"{res.message} ({res.wall_time:.0f} s)")
    print(f"wrote {out}/fit.json, fit.csv, fit.png, loss.png, case.toml")
    return 0 if res.converged else 1


def _figures(res, x, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    style = "o" if res.kind == "max_force" else "."
    ax.plot(x, res.measured / 1e3, style, label="measured")
    ax.plot(x, res.prediction / 1e3, "-", label=f"fit ({res.contact})")
    ax.set(xlabel="speed [km/h]" if res.kind == "max_force" else "time [s]",
           ylabel="max contact force [kN]" if res.kind == "max_force" else "contact force [kN]")
    ax.legend()
    save_figure(fig, out / "fit.png")
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.semilogy(np.arange(len(res.loss_history)), res.loss_history, "o-")
    ax.set(xlabel="iteration", ylabel="loss (mean squared relative residual)")
    save_figure(fig, out / "loss.png")

"""One accuracy table: the error of any numerical setting against a fixed converged reference
(issues 32 and 33).

Run: ``python benchmarks/accuracy_table.py [--quick] [--only LABEL ...]``. Writes
``benchmarks/results/accuracy_table.json`` (every measured number) and prints the Markdown
table of ``docs/convergence.md``.

Reference: 26 rail elements per bay, track modes to 20 kHz, time step 6.25 us and travel step
0.25 mm, 70 bays (45.5 m) with the fitted passive end networks (``Track.ends``; since
2026-12-05, late: the rows "reference, absorbing ends", three absorbing sleepers at each end,
the reference before, and "reference, clamped ends"), contact element 1 mm.
Each row changes the settings named in its label and keeps the rest of the reference, except
the rows labelled "default", which are whole configurations: today's (``SimConfig``'s auto
settings, which a run resolves by what it reads: a detector's reading gets 15 kHz, 25 us,
float64, ``wfjax.params.READING_SETTINGS``; end networks from 4 bays since 2026-12-06), the
one before it (absorbing ends on 24 bays; and the same with clamped ends) and the one before
2026-12-03 ("old default").

Sets (R_R = 0.45 m, ``Track.comparison()``):

- ``fig7``: the paper's Fig. 7 set, rounded 0.9 mm x 100 mm and new 0.9 mm, 3D contact (exact
  table), 20-300 km/h every 10 km/h, 5 impact positions per bay: max and min force, first
  loss-of-contact speed.
- ``sharp``: new flats 0.9 mm at 120, 160 and 200 km/h, Hertz-trajectory, 10 impact
  positions, with the seat forces of the bay's two sleepers: max and min force, max seat
  force; and the same runs with the 3-bay detector: its reading (largest bay; a detector
  lengthens the track to ``params.READING_BAYS``, so rows of shorter tracks read NaN).
- receptances of the track model alone, 20 Hz - 2 kHz (40 log-spaced points): rail
  displacement (point at 0.3 m, transfer 0.3 -> 1.0 m) and rail shear (0.3 -> 1.0 m and
  0.3 -> -0.45 m), from the modal model with its static correction.

Receptances whose sensor the guards refuse on a row's track (closer than
``wfjax.scenario.guards.sensor_margin`` to the ends: rows "bays 16" and "bays 20") are NaN;
rows with ``"lengthen"`` measure them on the track a run with those sensors gets
(``guards.holding_instruments``).

Errors: max and min force, seat force and detector reading run by run, relative to the
reference run's value, the largest over the set (min force: relative to the static wheel load,
since it goes to 0); loss-of-contact speed: the first speed of the 10 km/h grid where any
impact position loses contact, and its difference in km/h; receptances: the largest over
frequency of |H - H_ref| / |H_ref|.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import pathlib
import time

import numpy as np

import wfjax as wf
from wfjax.model import track as track_mod
from wfjax.params import READING_BAYS
from wfjax.scenario import guards
from wfjax.scenario import sensors as sensor_mod

REF = {"elements_per_bay": 26, "track_max_frequency": 20e3, "time_step": 6.25e-6,
       "travel_step": 0.25e-3, "n_bays": 70, "contact_element": 1e-3, "precision": "float64",
       "absorbing_sleepers": 0, "ends": "network"}  # since 2026-12-05, late: end networks
ABSORBING = {"absorbing_sleepers": 3, "ends": "absorbing"}  # the ends before
OLD = {"elements_per_bay": 8, "track_max_frequency": 10e3, "time_step": 25e-6,
       "travel_step": 1e-3, "n_bays": 70, "absorbing_sleepers": 0,
       "ends": "absorbing"}  # before 2026-12-03
NEW = {**OLD, "elements_per_bay": 26, "track_max_frequency": 15e3, "n_bays": 24,
       "precision": "float32", "time_step": 40e-6, **ABSORBING}  # today's force
# settings: float32 forward runs and 40 us since 2026-12-04, absorbing ends since the evening
# the package's defaults before 2026-12-06 (absorbing ends, 24 bays): SimConfig's auto
# settings, which a run resolves by what it reads (since 2026-12-05 12 kHz, 40 us, float32; a
# detector's reading 15 kHz, 25 us, float64 on at least 36 bays); since 2026-12-06 the default
# is NETWORK from 4 bays (Track.ends "auto": networks on the default track)
DEFAULT = {**NEW, "track_max_frequency": "auto", "time_step": "auto", "precision": "auto"}
CLAMPED_MARGINS = {"NETWORK_END_FACTOR": 3.0, "NETWORK_SENSOR_END_FACTOR": 8.5,
                   "NETWORK_READING_BAYS": 36}  # the guards' constants from clamped ends
NETWORK = {**DEFAULT, "absorbing_sleepers": 0, "ends": "network", "n_bays": 18,
           "lengthen": True}  # receptances on the track a run with their sensors gets
ROWS = {  # label -> changes to REF
    "reference": {},
    "reference, absorbing ends": ABSORBING,
    "default (26 el., end networks from 4 bays, the guards' margins for them; 12 kHz, 40 us "
    "/ 1 mm, float32; reading: 15 kHz, 25 us, float64, 24 bays)": {**NETWORK, "n_bays": 4},
    "default with end networks, the clamped ends' margins (18 bays; reading: 36 bays)": {
        **NETWORK, "guards": CLAMPED_MARGINS},
    "default with end networks, the clamped ends' margins, 14 bays": {
        **NETWORK, "n_bays": 14, "guards": CLAMPED_MARGINS},
    **{f"default with end networks, margins 0.5 / beta, reading on at least {n} bays": {
        **NETWORK, "n_bays": 4, "guards": {
            "NETWORK_END_FACTOR": 0.5, "NETWORK_SENSOR_END_FACTOR": 0.5,
            "NETWORK_READING_BAYS": n}} for n in (4, 14, 20, 26)},
    **{f"default with end networks, margins 0.5 / beta, sensors {f:g} / beta": {
        **NETWORK, "n_bays": 4, "guards": {
            "NETWORK_END_FACTOR": 0.5, "NETWORK_SENSOR_END_FACTOR": f,
            "NETWORK_READING_BAYS": 4}} for f in (1.0, 2.0, 3.0, 4.0, 6.0)},
    "reference, clamped ends": {"absorbing_sleepers": 0, "ends": "absorbing"},
    "default before 2026-12-06 (26 el., absorbing ends, 24 bays; 12 kHz, 40 us / 1 mm, "
    "float32; reading: 15 kHz, 25 us, float64, 36 bays)": DEFAULT,
    "default, clamped ends": {**DEFAULT, "absorbing_sleepers": 0, "ends": "absorbing"},
    "26 el., 15 kHz, 40 us / 1 mm, 24 bays, float32": NEW,
    "26 el., 15 kHz, 25 us / 1 mm, 24 bays, float32": {**NEW, "time_step": 25e-6},
    "26 el., 15 kHz, 25 us / 1 mm, 24 bays, float64": {**NEW, "time_step": 25e-6,
                                                       "precision": "float64"},
    "old default (8 el., 10 kHz, 25 us / 1 mm, 70 bays)": OLD,
    "step 50 us / 2 mm, absorbing ends": {**ABSORBING, "time_step": 50e-6, "travel_step": 2e-3},
    "step 100 us / 4 mm, absorbing ends": {**ABSORBING, "time_step": 100e-6, "travel_step": 4e-3},
    "step 200 us / 8 mm, absorbing ends": {**ABSORBING, "time_step": 200e-6, "travel_step": 8e-3},
    "modes 2 kHz, absorbing ends": {**ABSORBING, "track_max_frequency": 2e3},
    "modes 5 kHz, absorbing ends": {**ABSORBING, "track_max_frequency": 5e3},
    "modes 10 kHz, absorbing ends": {**ABSORBING, "track_max_frequency": 10e3},
    "modes 15 kHz, absorbing ends": {**ABSORBING, "track_max_frequency": 15e3},
    "bays 16, absorbing ends": {**ABSORBING, "n_bays": 16},
    "bays 20, absorbing ends": {**ABSORBING, "n_bays": 20},
    "bays 24, absorbing ends": {**ABSORBING, "n_bays": 24},
    "bays 36, absorbing ends": {**ABSORBING, "n_bays": 36},
    "mesh 2, absorbing ends": {**ABSORBING, "elements_per_bay": 2},
    "mesh 4, absorbing ends": {**ABSORBING, "elements_per_bay": 4},
    "mesh 8, absorbing ends": {**ABSORBING, "elements_per_bay": 8},
    "mesh 16, absorbing ends": {**ABSORBING, "elements_per_bay": 16},
    "step 25 us / 1 mm, absorbing ends": {**ABSORBING, "time_step": 25e-6, "travel_step": 1e-3},
    "step 12.5 us / 0.5 mm, absorbing ends": {**ABSORBING, "time_step": 12.5e-6,
                                              "travel_step": 0.5e-3},
    "bays 50, absorbing ends": {**ABSORBING, "n_bays": 50},
    "element 2 mm, absorbing ends": {**ABSORBING, "contact_element": 2e-3},
    "16 el., 10 kHz, 25 us / 1 mm, 70 bays": {**OLD, "elements_per_bay": 16},
    "8 el., 15 kHz, 25 us / 1 mm, 70 bays": {**OLD, "track_max_frequency": 15e3},
    "26 el., 12 kHz, 25 us / 1 mm, 30 bays": {**OLD, "elements_per_bay": 26,
                                              "track_max_frequency": 12e3, "n_bays": 30},
    "16 el., 15 kHz, 25 us / 1 mm, 30 bays": {**OLD, "elements_per_bay": 16,
                                              "track_max_frequency": 15e3, "n_bays": 30},
    "16 el., 12.5 kHz, 25 us / 1 mm, 24 bays": {**OLD, "elements_per_bay": 16,
                                                "track_max_frequency": 12.5e3, "n_bays": 24},
    "26 el., 15 kHz, 35 us / 1 mm, 24 bays": {**NEW, "time_step": 35e-6},
    "26 el., 15 kHz, 50 us / 1 mm, 24 bays": {**NEW, "time_step": 50e-6},
    "26 el., 15 kHz, 65 us / 1 mm, 24 bays": {**NEW, "time_step": 65e-6},
    "26 el., 15 kHz, 50 us / 1.5 mm, 24 bays": {**NEW, "time_step": 50e-6,
                                                "travel_step": 1.5e-3},
    # the reading needs a longer track, higher modes, a finer step: a detector's settings
    "26 el., 20 kHz, 25 us / 1 mm, 36 bays, float64": {
        **NEW, "track_max_frequency": 20e3, "time_step": 25e-6, "n_bays": 36,
        "precision": "float64"},
    "26 el., 20 kHz, 25 us / 1 mm, 60 bays, float64": {
        **NEW, "track_max_frequency": 20e3, "time_step": 25e-6, "n_bays": 60,
        "precision": "float64"},
    "26 el., 20 kHz, 40 us / 1 mm, 50 bays, float32": {**NEW, "track_max_frequency": 20e3,
                                                       "n_bays": 50},
    "26 el., 20 kHz, 40 us / 1 mm, 60 bays, float32": {**NEW, "track_max_frequency": 20e3,
                                                       "n_bays": 60},
    "26 el., 15 kHz, 40 us / 1 mm, 60 bays, float32": {**NEW, "n_bays": 60},
    "26 el., 20 kHz, 40 us / 1 mm, 70 bays, float32": {**NEW, "track_max_frequency": 20e3,
                                                       "n_bays": 70},
    "26 el., 20 kHz, 40 us / 1 mm, 70 bays, float64": {**NEW, "track_max_frequency": 20e3,
                                                       "n_bays": 70, "precision": "float64"},
    "26 el., 20 kHz, 25 us / 1 mm, 70 bays, float32": {**NEW, "track_max_frequency": 20e3,
                                                       "n_bays": 70, "time_step": 25e-6},
    "26 el., 20 kHz, 25 us / 1 mm, 24 bays, float64": {
        **NEW, "track_max_frequency": 20e3, "time_step": 25e-6, "precision": "float64"},
    # lower cut-offs, since the truncated modes' damper augmentation (2026-12-05)
    "26 el., 10 kHz, 40 us / 1 mm, 24 bays, float32": {**NEW, "track_max_frequency": 10e3},
    "26 el., 12 kHz, 40 us / 1 mm, 24 bays, float32": {**NEW, "track_max_frequency": 12e3},
    "26 el., 10 kHz, 25 us / 1 mm, 36 bays, float64": {
        **NEW, "track_max_frequency": 10e3, "time_step": 25e-6, "n_bays": 36,
        "precision": "float64"},
    "26 el., 15 kHz, 25 us / 1 mm, 36 bays, float64": {
        **NEW, "time_step": 25e-6, "n_bays": 36, "precision": "float64"},
}
FREQS = np.geomspace(20.0, 2000.0, 40)
RECEPTANCES = {  # name -> (quantity, force position [m], response position [m])
    "disp point 0.3": ("rail_disp", 0.3, 0.3),
    "disp 0.3->1.0": ("rail_disp", 0.3, 1.0),
    "shear 0.3->1.0": ("shear", 0.3, 1.0),
    "shear 0.3->-0.45": ("shear", 0.3, -0.45),
}
SEAT_SENSORS = [0.01, 0.64]  # m: the seat forces of the sleepers at 0 and 0.65 m


def settings(label: str) -> dict:
    """The reference with row ``label``'s changes."""
    return {**REF, **ROWS[label]}


def model_inputs(s: dict):
    """(Track, SimConfig) of the settings ``s`` (``"auto"``: SimConfig's auto setting)."""
    track = wf.Track.comparison(elements_per_bay=s["elements_per_bay"], n_bays=s["n_bays"],
                                absorbing_sleepers=s["absorbing_sleepers"],
                                ends=s.get("ends", "absorbing"))
    auto = {k: None if s[k] == "auto" else s[k] for k in ("time_step", "track_max_frequency")}
    config = wf.SimConfig(max_time_step=auto["time_step"], max_travel_step=s["travel_step"],
                          track_max_frequency=auto["track_max_frequency"],
                          contact_element=s.get("contact_element", 1e-3),
                          precision=s.get("precision", "float64"),
                          allow_inaccurate=True)  # the table measures what the guards refuse
    return track, config


def run_fig7(s: dict, quick: bool) -> dict:
    """Max/min force [N] [2, n_speeds, n_positions] and speeds [km/h] of the Fig. 7 set."""
    track, config = model_inputs(s)
    speeds = np.arange(20.0, 301.0, 40.0 if quick else 10.0)
    flats = [wf.Flat.rounded(0.9e-3, 0.1), wf.Flat.new(0.9e-3)]
    r = wf.sweep(flats, speeds / 3.6, 3 if quick else 5, contact="3d", track=track,
                 config=config, progress=False)
    return {"speeds_kmh": speeds.tolist(), "max_force": np.asarray(r.max_force).tolist(),
            "min_force": np.asarray(r.min_force).tolist(),
            "loss": np.asarray(r.loss_of_contact).tolist()}


def run_sharp(s: dict, quick: bool) -> dict:
    """Max/min force, max seat force and detector reading [N], [n_speeds, n_positions].

    The forces and seat forces come from runs without a detector, the reading from the same
    runs with one, whose track is at least ``params.READING_BAYS`` long and whose auto
    settings are the reading's: a row whose track is shorter reads NaN (it cannot carry a
    detector), except a row of auto settings (the package's defaults)."""
    track, config = model_inputs(s)
    speeds = np.array([120.0, 200.0] if quick else [120.0, 160.0, 200.0])
    kw = dict(contact="hertz-trajectory", track=track, config=config, progress=False)
    flat, positions = wf.Flat.new(0.9e-3), 4 if quick else 10
    r = wf.sweep(flat, speeds / 3.6, positions, sensors=SEAT_SENSORS,
                 sensor_quantities=("seat_force",), **kw)
    seat = np.asarray(r.sensor_max)[0, :, :, 0, :].max(axis=-1)
    out = {"speeds_kmh": speeds.tolist(), "max_force": np.asarray(r.max_force)[0].tolist(),
           "min_force": np.asarray(r.min_force)[0].tolist(), "seat_force": seat.tolist()}
    if s["n_bays"] < READING_BAYS and s["track_max_frequency"] != "auto":  # not a default
        out["reading"] = np.full(np.shape(seat), np.nan).tolist()
    else:
        d = wf.sweep(flat, speeds / 3.6, positions, detector=wf.Detector(), **kw)
        out["reading"] = np.asarray(d.detector_peak)[0].max(axis=-1).tolist()
    return out


def run_receptances(s: dict) -> dict:
    """Complex receptances [n_f] as [re, im] lists: displacement [m/N], shear [N/N]."""
    track, config = model_inputs(s)
    if s.get("lengthen"):  # as a run with these sensors lengthens the track
        track = guards.holding_instruments(track, [0.3, 1.0, -0.45])
    model = track_mod.modal_model(track, max_frequency=config.resolved().track_max_frequency)
    out = {"n_bays": int(track.n_bays)}
    for name, (quantity, xf, xr) in RECEPTANCES.items():
        try:
            h = sensor_mod.transfer_receptance(track, model, FREQS, xf, xr, quantity)
        except ValueError:  # a sensor the guards refuse on this short a track: NaN
            h = np.full(FREQS.size, np.nan + 0j)
        out[name] = [h.real.tolist(), h.imag.tolist()]
    out["n_modes"] = int(np.asarray(model.poles).size)
    return out


def first_loss_speed(speeds, loss) -> float:
    """First speed [km/h] at which any impact position loses contact (nan: none)."""
    hit = np.asarray(loss).any(axis=-1)
    return float(speeds[np.argmax(hit)]) if hit.any() else float("nan")


def errors(run: dict, ref: dict, static_load: float) -> dict:
    """The row's errors against the reference (see the module doc)."""
    e = {}
    for name in ("fig7", "sharp"):
        a, b = run[name], ref[name]
        e[f"{name} max force %"] = 100 * _rel(a["max_force"], b["max_force"])
        e[f"{name} min force %P"] = 100 * float(np.max(np.abs(
            np.subtract(a["min_force"], b["min_force"])))) / static_load
    for key, label in (("seat_force", "seat force %"), ("reading", "detector reading %")):
        e[label] = 100 * _rel(run["sharp"][key], ref["sharp"][key])
    sp = np.asarray(ref["fig7"]["speeds_kmh"])
    for i, kind in enumerate(("rounded", "new")):
        e[f"loss speed {kind} km/h"] = (
            first_loss_speed(sp, np.asarray(run["fig7"]["loss"])[i])
            - first_loss_speed(sp, np.asarray(ref["fig7"]["loss"])[i]))
    e["modes"] = run["receptances"]["n_modes"]
    for name in RECEPTANCES:
        h = np.asarray(run["receptances"][name][0]) + 1j * np.asarray(
            run["receptances"][name][1])
        h0 = np.asarray(ref["receptances"][name][0]) + 1j * np.asarray(
            ref["receptances"][name][1])
        e[f"{name} %"] = 100 * float(np.max(np.abs(h - h0) / np.abs(h0)))
    return e


def _rel(a, b) -> float:
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b) / np.abs(b)))


@contextlib.contextmanager
def candidate_guards(values: dict):
    """Within the block, the guards' constants ``values`` (name -> value) replace
    ``wfjax.scenario.guards``'s (``NETWORK_READING_BAYS``: ``wfjax.params``'s): rows that
    measure a candidate bound."""
    owner = {name: guards if hasattr(guards, name) else wf.params for name in values}
    kept = {name: getattr(owner[name], name) for name in values}
    for name, value in values.items():
        setattr(owner[name], name, value)
    try:
        yield
    finally:
        for name, value in kept.items():
            setattr(owner[name], name, value)


def measure(labels, quick: bool, path: pathlib.Path) -> dict:
    """Run every row of ``labels`` not yet in ``path`` with its settings (JSON, updated after
    each row)."""
    done = json.loads(path.read_text()) if path.exists() else {}
    for label in labels:
        s = settings(label)
        kept = done.get(label, {})
        if kept.get("quick") == quick and {"ends": "absorbing", **kept["settings"]} == s:
            continue
        t0 = time.perf_counter()
        with candidate_guards(s.get("guards", {})):
            done[label] = {"settings": s, "quick": quick, "fig7": run_fig7(s, quick),
                           "sharp": run_sharp(s, quick), "receptances": run_receptances(s)}
        done[label]["seconds"] = time.perf_counter() - t0
        print(f"{label}: {done[label]['seconds']:.0f} s", flush=True)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(done))
    return done


COLUMNS = ("modes", "fig7 max force %", "fig7 min force %P", "loss speed rounded km/h",
           "loss speed new km/h", "sharp max force %", "sharp min force %P", "seat force %",
           "detector reading %", "disp point 0.3 %", "disp 0.3->1.0 %", "shear 0.3->1.0 %",
           "shear 0.3->-0.45 %")


def table(done: dict) -> str:
    """The Markdown accuracy table of every measured row against the reference."""
    ref, load = done["reference"], wf.Wheel().preload
    lines = ["| setting | " + " | ".join(COLUMNS) + " | s |",
             "| --- |" + " --- |" * (len(COLUMNS) + 1)]
    for label in ROWS:
        if label not in done:
            continue
        e = errors(done[label], ref, load)
        cells = [f"{e[c]:+.0f}" if "km/h" in c else str(e[c]) if c == "modes"
                 else f"{e[c]:.2f}" for c in COLUMNS]
        lines.append(f"| {label} | " + " | ".join(cells)
                     + f" | {done[label]['seconds']:.0f} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer speeds and positions")
    ap.add_argument("--only", nargs="*", default=None, help="row labels to (re)measure")
    ap.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results"
                                         / "accuracy_table.json"))
    a = ap.parse_args()
    labels = ["reference"] + [k for k in ROWS if k != "reference"
                              and (a.only is None or k in a.only)]
    print(table(measure(labels, a.quick, pathlib.Path(a.out))))


if __name__ == "__main__":
    main()

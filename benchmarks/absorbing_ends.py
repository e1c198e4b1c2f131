"""The absorbing track ends (``Track.absorbing_sleepers``) measured: the numbers of
docs/convergence.md, "Absorbing ends" (issue 33).

Sections (``--sections``, all by default):

* ``grading``: new 0.9 mm flat, 20, 40 and 120 km/h, 5 impact positions, Hertz-trajectory,
  R_R = 0.45 m, modes to 15 kHz, 40 us / 1 mm, float64: the largest min-force difference
  [kN] of a 24-bay track from a 50-bay clamped one, with clamped ends and with the end
  sleepers' pad and ballast damping multiplied by a few gradings (per-sleeper arrays,
  ``absorbing_sleepers=0``, so any grading can be tried; x2, 4, 8 is what
  ``absorbing_sleepers=3`` builds);
* ``rail``: the rail's end damping (``wfjax.model.fe.END_RAIL_DAMPING``, set here for each
  value with a cache of its own): new 0.9 mm flat, 20, 30 and 40 km/h, 5 impact positions,
  3D (exact tables), ``Track.comparison``, modes to 20 kHz, float64: the largest min-force
  difference [kN] of 24, 30 and 36 bays from 70 bays with the same ends, and the largest
  max-force difference [%];
* ``receptance``: the transfer receptance 0.3 -> 1.0 m and the point receptance at 0.3 m of
  the accuracy table's reference (70 bays, 26 el., 20 kHz) and of the default (24 bays,
  the force's auto cut-off: 12 kHz since 2026-12-05), with and without the absorbing ends,
  against the infinite periodic track (``wfjax.track.periodic_receptance``) on the accuracy
  table's 40 frequencies and on a fine grid (``FINE``: 0.2 Hz steps over 900-1000 Hz, which
  the 40 frequencies step over): largest relative difference [%], and outside 850-1050 Hz;
  and the infinite track's transfer receptance peak with its half-power band;
* ``layers``: other end treatments of the default's 24 bays, solved directly (sparse FE, no
  modes, so the treatment alone is measured): the rail's mass-proportional end damping over
  4, 6 or 8 bays at each end (quadratic, up to 3,000 or 10,000 1/s), and rotational dampers
  on the rail at the sleepers (graded the same way over 8 bays, up to 1e3 or 1e4 N m s; they
  act where a pinned-pinned wave's slope is largest), each on top of the sleepers' grading:
  the largest relative difference [%] of the point (0.3 m) and transfer (0.3 -> 1.0 m)
  receptances from the infinite periodic track on the 40 frequencies, and outside 850-1050
  Hz;
* ``timing``: whole-process warm wall times [s] of ``wfjax detector`` on 36 and 60 bays and
  of ``wfjax figures --only 8`` with and without the absorbing ends, ``--rounds`` alternated
  rounds after one unrecorded warm-up of each.

Run: ``python benchmarks/absorbing_ends.py [--sections grading,rail,receptance,layers,timing]
[--rounds 3]``; writes ``benchmarks/results/absorbing_ends.json`` and prints the figures.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import sys
import tempfile
import time

import numpy as np

import wfjax as wf
from wfjax.model import track as track_mod
from wfjax.model.periodic import periodic_receptance
from wfjax.scenario import sensors as sensor_mod

GRADINGS = {"clamped": None, "x2, 4, 8": [2, 4, 8], "x1.5, 2, 3, 5, 8": [1.5, 2, 3, 5, 8],
            "x3, 10, 30": [3, 10, 30]}
FREQS = np.geomspace(20.0, 2000.0, 40)  # the accuracy table's
TIMED = {"detector, 36 bays": ["detector", "--set", "track.n_bays=36"],
         "detector, 60 bays": ["detector", "--set", "track.n_bays=60"],
         "figures 8, absorbing ends": ["figures", "--only", "8"],
         "figures 8, clamped ends": ["figures", "--only", "8", "--set",
                                     "track.absorbing_sleepers=0"]}


def _graded(n_bays: int, ramp) -> wf.Track:
    """The comparison track, clamped ends, end sleepers' damping x ``ramp`` (outwards)."""
    track = wf.Track.comparison(n_bays=n_bays, absorbing_sleepers=0)
    if ramp is None:
        return track
    fac = np.ones(n_bays - 1)
    fac[:len(ramp)], fac[-len(ramp):] = ramp[::-1], ramp
    return wf.Track.comparison(n_bays=n_bays, absorbing_sleepers=0,
                               pad_damping=float(track.pad_damping) * fac,
                               ballast_damping=float(track.ballast_damping) * fac)


def grading() -> dict:
    """Largest min-force difference [kN] per speed from the 50-bay clamped track."""
    cfg = wf.SimConfig(track_max_frequency=15e3, precision="float64")
    speeds = np.array([20.0, 40.0, 120.0])

    def min_force(track):
        r = wf.sweep(wf.Flat.new(0.9e-3), speeds / 3.6, 5, contact="hertz-trajectory",
                     track=track, config=cfg, progress=False)
        return np.asarray(r.min_force)[0] / 1e3

    ref = min_force(_graded(50, None))
    return {"speeds_kmh": speeds.tolist(), **{
        name: np.abs(min_force(_graded(24, ramp)) - ref).max(axis=1).round(3).tolist()
        for name, ramp in GRADINGS.items()}}


RAIL_DAMPINGS = (0.0, 1000.0, 3000.0, 10000.0)  # 1/s


def rail() -> dict:
    """Per rail damping [1/s]: the largest min-force [kN] and max-force [%] differences of
    24, 30 and 36 bays from 70 bays."""
    from wfjax.model import fe

    cfg = wf.SimConfig(track_max_frequency=20e3, precision="float64")
    speeds = np.array([20.0, 30.0, 40.0])
    kept, out = fe.END_RAIL_DAMPING, {}
    try:
        for eta in RAIL_DAMPINGS:
            fe.END_RAIL_DAMPING = eta
            cache = tempfile.mkdtemp()  # the modal models' cache key does not hold it

            def run(n_bays, cache=cache):
                r = wf.sweep(wf.Flat.new(0.9e-3), speeds / 3.6, 5, contact="3d",
                             track=wf.Track.comparison(n_bays=n_bays), config=cfg,
                             progress=False, cache_dir=cache)
                return np.asarray(r.min_force)[0], np.asarray(r.max_force)[0]

            ref = run(70)
            for n in (24, 30, 36):
                lo, hi = run(n)
                out[f"{eta:g} 1/s, {n} bays"] = {
                    "min_force_kN": float(np.abs(lo - ref[0]).max() / 1e3),
                    "max_force_pct": float(100 * np.abs(hi / ref[1] - 1).max())}
                print(f"rail {eta:g} 1/s, {n} bays: {out[f'{eta:g} 1/s, {n} bays']}",
                      flush=True)
    finally:
        fe.END_RAIL_DAMPING = kept
    return out


LAYERS = {  # label -> (zone [bays], rail damping [1/s], rotational damping [N m s])
    "default: 4 bays, 3000 1/s": (4, 3000.0, 0.0),
    "6 bays, 3000 1/s": (6, 3000.0, 0.0), "8 bays, 3000 1/s": (8, 3000.0, 0.0),
    "6 bays, 10000 1/s": (6, 1e4, 0.0), "8 bays, 10000 1/s": (8, 1e4, 0.0),
    "8 bays, 3000 1/s, rotational 1e3": (8, 3000.0, 1e3),
    "8 bays, 3000 1/s, rotational 1e4": (8, 3000.0, 1e4)}


def _layer_damping(track, zone_bays: int, eta: float, rotational: float):
    """The FE model of ``track`` with the rail's end damping (``fe.end_rail_damping``'s
    form) over ``zone_bays`` at each end, up to ``eta`` [1/s], and its damping matrix plus
    rotational dampers [N m s] on the rail at the sleepers, graded alike (quadratically)."""
    import scipy.sparse

    from wfjax.model import fe as fe_mod

    ls = float(track.sleeper_spacing)

    def ramp(x, length, top):
        d = np.minimum(x, length - x)
        return top * np.clip(1.0 - d / (zone_bays * ls), 0.0, 1.0) ** 2

    kept = fe_mod.end_rail_damping
    try:
        fe_mod.end_rail_damping = lambda x, length, _zone: ramp(np.asarray(x), length, eta)
        model = fe_mod.assemble(track)
    finally:
        fe_mod.end_rail_damping = kept
    x_node = model.node_x[1:-1] - model.node_x[0]  # the free rail nodes [m from the left end]
    on_sleeper = np.abs(x_node / ls - np.round(x_node / ls)) < 1e-6
    rot = np.zeros(model.mass.shape[0])
    rot[1:model.n_rail_dof:2] = np.where(
        on_sleeper, ramp(x_node, int(track.n_bays) * ls, rotational), 0.0)
    return model, (model.damping + scipy.sparse.diags(rot)).tocsc()


def _direct(model, damping, freqs, x: float, xr: float) -> np.ndarray:
    """[n_f] receptance [m/N] from ``x`` to ``xr`` [m] by sparse solves (no modes)."""
    import scipy.sparse.linalg

    from wfjax.model import fe as fe_mod

    b = fe_mod.load_vector(model, np.array([x])).toarray()[:, 0].astype(complex)
    r = fe_mod.load_vector(model, np.array([xr])).toarray()[:, 0]
    out = []
    for f in freqs:
        w = 2 * np.pi * f
        a = (model.stiffness + 1j * w * damping - w * w * model.mass).tocsc()
        out.append(r @ scipy.sparse.linalg.spsolve(a, b))
    return np.asarray(out)


def layers() -> dict:
    """Per end treatment of 24 bays: the largest and the outside-850-1050-Hz relative
    differences [%] of the direct receptances from the infinite track's."""
    track = wf.Track.comparison(n_bays=24)
    band = (FREQS < 850) | (FREQS > 1050)
    out = {}
    for label, (zone, eta, rot) in LAYERS.items():
        model, c = _layer_damping(track, zone, eta, rot)
        for name, xr in (("point 0.3", 0.3), ("transfer 0.3->1.0", 1.0)):
            e = 100 * np.abs(_direct(model, c, FREQS, 0.3, xr)
                             / periodic_receptance(track, FREQS, 0.3, xr) - 1)
            out[f"{label}, {name}"] = [round(float(e.max()), 2), round(float(e[band].max()), 2)]
        print(f"layers {label}: {out[f'{label}, point 0.3']} {out[f'{label}, transfer 0.3->1.0']}",
              flush=True)
    return out


FINE = np.unique(np.concatenate([np.geomspace(20.0, 2000.0, 300),
                                 np.arange(900.0, 1000.0, 0.2)]))  # resolves the peak


def receptance() -> dict:
    """Largest / outside-850-1050-Hz relative difference [%] from the infinite track, on the
    accuracy table's 40 frequencies and on ``FINE``; and the infinite track's transfer
    receptance peak near pinned-pinned with its half-power band [Hz]."""
    out, default = {}, wf.SimConfig().resolved().track_max_frequency  # the force's cut-off
    for label, n_bays, f_max in (("reference", 70, 20e3), ("default", 24, default)):
        for ends in (3, 0):
            track = wf.Track.comparison(n_bays=n_bays, absorbing_sleepers=ends)
            model = track_mod.modal_model(track, max_frequency=f_max)
            for grid, f in (("", FREQS), (", fine", FINE)):
                band = (f < 850) | (f > 1050)
                for name, xr in (("point 0.3", 0.3), ("transfer 0.3->1.0", 1.0)):
                    h = sensor_mod.transfer_receptance(track, model, f, 0.3, xr)
                    e = 100 * np.abs(h / periodic_receptance(track, f, 0.3, xr) - 1)
                    out[f"{label}, absorbing {ends}, {name}{grid}"] = [
                        round(float(e.max()), 2), round(float(e[band].max()), 2)]
    f = FINE[(FINE > 900) & (FINE < 1000)]
    h = np.abs(periodic_receptance(wf.Track.comparison(), f, 0.3, 1.0))
    half = f[h >= h.max() / np.sqrt(2)]
    out["infinite track's transfer peak [Hz, m/N], half-power band [Hz]"] = [
        round(float(f[np.argmax(h)]), 1), float(h.max()), [round(float(half.min()), 1),
                                                           round(float(half.max()), 1)]]
    return out


def timing(rounds: int) -> dict:
    """Whole-process warm wall times [s], alternated rounds."""
    times: dict = {k: [] for k in TIMED}
    with tempfile.TemporaryDirectory() as work:
        def once(args):
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "wfjax", *args, "--out", work], check=True,
                           capture_output=True)
            return time.perf_counter() - t0

        for args in TIMED.values():
            once(args)  # fills the caches
        for _ in range(rounds):
            for name, args in TIMED.items():
                times[name].append(round(once(args), 2))
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sections", default="grading,rail,receptance,layers,timing")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results"
                                         / "absorbing_ends.json"))
    a = ap.parse_args()
    makers = {"grading": grading, "rail": rail, "receptance": receptance, "layers": layers,
              "timing": lambda: timing(a.rounds)}
    out = pathlib.Path(a.out)
    result = json.loads(out.read_text()) if out.exists() else {}  # other sections kept
    for name in a.sections.split(","):
        result[name] = makers[name]()
        out.write_text(json.dumps(result, indent=1))
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()

"""Non-reflecting track ends as a fitted passive network, measured in the frequency domain
(issue 33, "non-reflecting ends"; docs/convergence.md, "A fitted passive end network").

The exact end of a finite track is the semi-infinite track's boundary stiffness K_R(omega)
[2 x 2 on the end node's w, theta] (``wfjax.model.periodic``, cyclic reduction). A time-domain
model needs it as extra degrees of freedom: here ``n_aux`` internal DOFs joined to the end
node, with mass, damping and stiffness matrices M, C, K [(2 + n_aux)^2] written as
L L^T (so positive semi-definite: the network is passive and cannot destabilise the
track), and K_fit(omega) the Schur complement of K + i omega C - omega^2 M onto the end
node. The factors are fitted (L-BFGS, gradients by jax) to the relative Frobenius error of
K_fit against K_R (theta scaled by 0.1 m) on 10 Hz-``ends.BAND_TOP``, dense (0.25 Hz) around
the pinned-pinned resonance, and, weighted ``--hf-weight``, above it to 20 kHz. The stored
network was fitted with the band at 2.5 kHz; since 2026-12-06 ``ends.BAND_TOP`` is 2 kHz
(docs/convergence.md, "End networks"), so a new fit here uses that.

Then the default's 24 bays (26 el./bay, no modes: direct solves of the FE section) with the
network at both ends (the left end mirrored) against the infinite periodic track: the
largest relative difference [%] of the point (0.3 m) and transfer (0.3 -> 1.0 m)
receptances on the accuracy table's 40 frequencies, on a fine grid (300 log-spaced
frequencies and 0.2 Hz steps over 900-1000 Hz), outside 850-1050 Hz, and on 2-20 kHz; and
on the fine grid beside the band edge (``band_edge``: 943.32 Hz, where the undamped rail's
pinned-pinned wave stops travelling and the infinite track's receptance grows as
|f - f_edge|^-1/2, so that no finite track and no time window resolves it), leaving out
+-1 to 50 Hz around it, for the network and for the time-domain model's default and
reference with today's ends.
Today's ends (clamped, the sleepers' grading and the rail's end damping) give 15.6-20.4 % on
the 40 frequencies, 92-94 % on the fine grid (943.4 Hz) and 12-14 % outside 850-1050 Hz.

Section ``time``: the time-domain model with the network (``Track(ends="network")``,
:mod:`wfjax.model.ends`): a new flat's max and min forces on 24 bays with the network, with
the absorbing ends and clamped, against 70 bays with absorbing ends; and the network's modal
receptance beside the band edge.

Section ``speed``: warm seconds of the Fig. 7 set and of the sharp set with a detector on the
default track and with end networks from 4 bays (the guards' margins for end networks,
``benchmarks/network_margins.py``), alternated.

Section ``edge``: the band edge's figures (:func:`edge_figures`).

Section ``warm``: fits for other tracks (softer and stiffer pads, softer ballast, other
sleepers and meshes) started from the default's network, each way in turn: the library's
Levenberg-Marquardt fit along a path of tracks (``ends._fitted``, since 2026-12-06) and the
rounds of 800 L-BFGS iterations it replaced (``ends.fit`` until within ``ends.FIT_TOLERANCE``,
at most 5 rounds): how long a track's own network takes when a stored one is the start.

Run: ``python benchmarks/end_network.py [--sections fit,time,edge,warm] [--n-aux 24]
[--iterations 6000] [--seed 1]`` (fit about 7 minutes on 2 cores, time 1 minute; ``time``
alone uses the stored factors); writes ``benchmarks/results/end_network.json``. The fitted
factors are what ``wfjax/model/end_network_default.json`` stores (copied by hand, with the
track they were fitted to, after a new fit).
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import tempfile
import time

import jax
import numpy as np
import scipy.sparse
import scipy.sparse.linalg
from absorbing_ends import FINE  # the fine grid that resolves the band edge

import wfjax as wf
from wfjax.model import ends
from wfjax.model import periodic as P

jax.config.update("jax_enable_x64", True)

def _track():
    track = wf.Track.comparison()
    p, ne = P._numbers(track), int(track.elements_per_bay)
    return track, p, ne, P._cell_matrices(p, ne)


def fit(iterations: int, seed: int, track=None, start=None) -> tuple:
    """The fitted factors (from ``start``, else a random start drawn with ``seed``) and the
    fit's largest / median relative error in 10-2500 Hz and where the largest is [Hz]."""
    track = wf.Track.comparison() if track is None else track
    n = ends.N_AUX + 2
    tri, nt = np.tril_indices(n), n * (n + 1) // 2
    if start is None:
        start = 0.5 * np.random.default_rng(seed).normal(size=3 * nt)
        diag = np.flatnonzero(tri[0] == tri[1])
        for i in range(3):
            start[i * nt + diag] = np.abs(start[i * nt + diag]) + 1.0
    x = ends.fit(track, start, iterations)
    band = ends._grid(ends.band_edge(track))[0]
    band = band[band <= 2500]  # the stored network's band (the warm fits': ends.BAND_TOP)
    e = np.asarray(jax.jit(ends._relative_error(track, band))(x))
    return x, float(e.max()), float(np.median(e)), float(band[np.argmax(e)])


def receptance_errors(x) -> dict:
    """Largest relative differences [%] of 24 bays with the network at both ends from the
    infinite periodic track, per frequency set and receptance."""
    track, p, ne, (k, m, c, phi) = _track()
    mats = ends.matrices(np.asarray(x))
    nb, ls = 24, float(p["sleeper_spacing"])
    loads = P._nodal_loads(np.array([0.3, 0.3, 1.0]) + (nb // 2) * ls, ls / ne, ne, nb, phi)
    mirror = np.diag([1.0, -1.0])

    def solve(f):
        out = []
        for fi in f:
            w = 2 * math.pi * fi
            k_r = ends.network_stiffness(mats, np.array([w]))[0]
            pad = p["pad_stiffness"] + 1j * w * p["pad_damping"]
            ground = p["ballast_stiffness"] + 1j * w * p["ballast_damping"]
            sleeper = pad - pad**2 / (pad + ground - w * w * p["sleeper_mass"])
            # the section's first node carries its first cell's sleeper: K_L leaves it out
            k_l = mirror @ k_r @ mirror - np.diag([sleeper, 0.0])
            d = scipy.sparse.csc_matrix(P._section(k - w * w * m + 1j * w * c, nb, k_l, k_r))
            out.append(loads[:, 1:].T @ scipy.sparse.linalg.spsolve(d, loads[:, 0] + 0j))
        return np.array(out)

    sets = {"40 frequencies": np.geomspace(20, 2000, 40), "fine": FINE,
            "2-20 kHz": np.geomspace(2000, 20000, 150)}
    out, solved = {}, {}
    for name, f in sets.items():
        solved[name] = solve(f)
        e = 100 * np.abs(solved[name] / P.periodic_receptance(track, f, 0.3,
                                                              np.array([0.3, 1.0])) - 1)
        outside = (f < 850) | (f > 1050)
        for j, label in enumerate(("point 0.3", "transfer 0.3->1.0")):
            out[f"{name}, {label}"] = {
                "max_pct": round(float(e[:, j].max()), 3),
                "at_Hz": round(float(f[np.argmax(e[:, j])]), 1),
                "outside_850_1050_max_pct": round(float(e[outside, j].max()), 3),
                "median_pct": round(float(np.median(e[:, j])), 3)}
            print(name, label, out[f"{name}, {label}"], flush=True)
    out["fine, beside the band edge"] = beside_band_edge(solved["fine"])
    return out


EXCLUDED_HZ = (0.0, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0)


def band_edge(track=None) -> float:
    """[Hz] the comparison track's (or ``track``'s) band edge
    (:func:`wfjax.model.ends.band_edge`)."""
    return ends.band_edge(wf.Track.comparison() if track is None else track)


def edge_figures() -> dict:
    """The band edge [Hz], |H| [m/N] of the infinite track's transfer receptance 0.3 -> 1.0 m
    at 1, 0.1, 0.01 Hz and 0 from it (|f - f_edge|^-1/2 grows a decade in |H| per two
    decades in f), and the slower wave's decay there [Np per bay]."""
    edge, track = band_edge(), wf.Track.comparison()
    offsets = np.array([-1.0, -0.1, -0.01, 0.0, 0.01, 0.1, 1.0])
    h = np.abs(P.periodic_receptance(track, edge + offsets, 0.3, 1.0))
    lam = P.floquet_multipliers(track, [edge])[0]
    return {"band_edge_Hz": round(edge, 4), "offsets_Hz": offsets.tolist(),
            "abs_H_m_per_N": [float(f"{v:.3g}") for v in h],
            "slower_wave_decay_Np_per_bay": float(f"{-np.log(abs(lam[1])):.3g}")}


def beside_band_edge(network: np.ndarray) -> dict:
    """Largest relative difference [%] (point and transfer) from the infinite track on
    ``FINE`` outside +-``EXCLUDED_HZ`` of the band edge, for the network's 24 bays
    (``network`` [n_f, 2]) and the time-domain model's default (24 bays) and reference (70
    bays, 20 kHz) with today's absorbing ends."""
    from wfjax.model import track as track_mod
    from wfjax.scenario import sensors as sensor_mod

    edge = band_edge()
    ref = P.periodic_receptance(wf.Track.comparison(), FINE, 0.3, np.array([0.3, 1.0]))
    rows = {"network, 24 bays": network}
    for label, n_bays, f_max in (("default, 24 bays", 24,
                                  wf.SimConfig().resolved().track_max_frequency),
                                 ("reference, 70 bays", 70, 20e3)):
        track = wf.Track.comparison(n_bays=n_bays)
        model = track_mod.modal_model(track, max_frequency=f_max)
        rows[label] = np.stack([sensor_mod.transfer_receptance(track, model, FINE, 0.3, xr)
                                for xr in (0.3, 1.0)], axis=1)
    out = {"band_edge_Hz": round(edge, 4)}
    for label, h in rows.items():
        e = 100 * np.abs(h / ref - 1).max(axis=1)
        out[label] = {f"+-{d:g} Hz": round(float(e[np.abs(FINE - edge) > d].max()), 2)
                      for d in EXCLUDED_HZ}
        print(label, out[label], flush=True)
    return out


TIME_SPEEDS_KMH = np.array([20.0, 40.0, 120.0, 200.0])


def time_domain() -> dict:
    """The network in the time-domain model: new 0.9 mm flat at ``TIME_SPEEDS_KMH``, 5
    impact positions, Hertz-trajectory, R_R = 0.45 m, the default's settings in float64:
    per track, its modes and the largest max-force [%] and min-force [kN] differences per
    speed from 70 bays with today's ends; and the network's modal receptance beside the
    band edge."""
    from wfjax.model import track as track_mod
    from wfjax.scenario import sensors as sensor_mod

    cfg = wf.SimConfig(precision="float64")

    def run(track):
        r = wf.sweep(wf.Flat.new(0.9e-3), TIME_SPEEDS_KMH / 3.6, 5, contact="hertz-trajectory",
                     track=track, config=cfg, progress=False, cache_dir=tempfile.mkdtemp())
        return (np.asarray(r.max_force)[0], np.asarray(r.min_force)[0] / 1e3,
                int(r.settings["n_modes"]))

    ref = run(wf.Track.comparison(n_bays=70))
    rows = {"24 bays, today's ends": run(wf.Track.comparison(n_bays=24)),
            "24 bays, clamped": run(wf.Track.comparison(n_bays=24, absorbing_sleepers=0))}
    track = wf.Track.comparison(n_bays=24, ends="network")
    rows["24 bays, network"] = run(track)
    model = track_mod.modal_model(track, use_cache=False,
                                  max_frequency=cfg.resolved().track_max_frequency)
    h = np.stack([sensor_mod.transfer_receptance(track, model, FINE, 0.3, xr)
                  for xr in (0.3, 1.0)], axis=1)
    out = {"speeds_kmh": TIME_SPEEDS_KMH.tolist(), "70 bays, today's ends: modes": ref[2]}
    for label, (hi, lo, modes) in rows.items():
        out[label] = {"modes": modes,
                      "max_force_pct": (100 * np.abs(hi / ref[0] - 1)).max(axis=1).round(4)
                      .tolist(),
                      "min_force_kN": np.abs(lo - ref[1]).max(axis=1).round(4).tolist()}
        print(label, out[label], flush=True)
    out["network's modal receptance beside the band edge"] = _beside(h)
    return out


def _beside(h) -> dict:
    edge = band_edge()
    ref = P.periodic_receptance(wf.Track.comparison(), FINE, 0.3, np.array([0.3, 1.0]))
    e = 100 * np.abs(h / ref - 1).max(axis=1)
    return {f"+-{d:g} Hz": round(float(e[np.abs(FINE - edge) > d].max()), 2) for d in EXCLUDED_HZ}


WARM_TRACKS = {"pads 60 MN/m": {"pad_stiffness": 60e6},
               "pads 240 MN/m": {"pad_stiffness": 240e6},
               "ballast 70 MN/m": {"ballast_stiffness": 70e6},
               "sleepers 0.6 m apart": {"sleeper_spacing": 0.6},
               "sleepers 0.7 m apart": {"sleeper_spacing": 0.7},
               "pads 500 MN/m": {"pad_stiffness": 500e6},
               "pads 30 MN/m": {"pad_stiffness": 30e6},
               "8 elements per bay": {"elements_per_bay": 8}}
LBFGS_ROUNDS = 5  # the replaced warm fit: rounds of 800 L-BFGS iterations before a refusal


def _lbfgs_rounds(track) -> np.ndarray:
    """The warm fit before 2026-12-06: rounds of 800 L-BFGS iterations from the stored network
    until within ``ends.FIT_TOLERANCE``; raises ValueError after ``LBFGS_ROUNDS``."""
    x = np.asarray(ends.stored()["factors"], dtype=float)
    for _ in range(LBFGS_ROUNDS):
        x = ends.fit(track, x, 800)
        if ends.fit_error(track, x) <= ends.FIT_TOLERANCE:
            return x
    raise ValueError(f"{100 * ends.fit_error(track, x):.1f} % after {LBFGS_ROUNDS} rounds")


def warm() -> dict:
    """What a track other than the default costs, both ways (module docstring), alternating
    which goes first: seconds (the band edge computed before the clock), the fit's error
    beside the band edge [%] and the band edge [Hz], or why it was refused."""
    out = {}
    for i, (label, changes) in enumerate(WARM_TRACKS.items()):
        track = wf.Track.comparison(ends="network", **changes)
        row = {"band_edge_Hz": round(ends.band_edge(track), 2)}
        ways = [("levenberg_marquardt", ends._fitted), ("lbfgs_rounds", _lbfgs_rounds)]
        for way, fitter in ways[::-1] if i % 2 else ways:
            t0 = time.perf_counter()
            try:
                err = 100 * ends.fit_error(track, fitter(track))
                row[way] = {"beside_edge_max_pct": round(err, 2)}
            except ValueError as exc:
                row[way] = {"refused": str(exc)}
            row[way]["s"] = round(time.perf_counter() - t0, 1)
        out[label] = row
        print(label, row, flush=True)
    return out


SPEED_TRACKS = {"absorbing ends (the default before 2026-12-06)": {"n_bays": 24,
                                                                  "ends": "absorbing"},
                "end networks, n_bays=4 (the default)": {"n_bays": 4, "ends": "network"}}


def speed(rounds: int = 3) -> dict:
    """Warm seconds (median of ``rounds``, the tracks alternated) of the Fig. 7 set (3D,
    rounded and new 0.9 mm flats, 20-300 km/h, 5 positions: 290 runs) and of the sharp set
    with the 3-bay detector (new 0.9 mm, 120-200 km/h, 10 positions), on the default track
    and with end networks from 4 bays (lengthened by the guards); their bays and modes."""
    flats = [wf.Flat.rounded(0.9e-3, 0.1), wf.Flat.new(0.9e-3)]
    jobs = {"fig7": lambda tr: wf.sweep(flats, np.arange(20, 301, 10) / 3.6, 5, track=tr,
                                         progress=False),
            "detector": lambda tr: wf.sweep(flats[1], np.array([120, 160, 200]) / 3.6, 10,
                                             contact="hertz-trajectory", track=tr,
                                             detector=wf.Detector(), progress=False)}
    out = {}
    for job, run in jobs.items():
        times = {label: [] for label in SPEED_TRACKS}
        for label, kw in SPEED_TRACKS.items():  # warm-up: compile, tables, modal models
            r = run(wf.Track.comparison(**kw))
            out.setdefault(job, {})[label] = {"n_bays": r.settings["n_bays"],
                                              "n_modes": r.settings["n_modes"]}
        for _ in range(rounds):
            for label, kw in SPEED_TRACKS.items():
                t0 = time.perf_counter()
                run(wf.Track.comparison(**kw))
                times[label].append(time.perf_counter() - t0)
        for label in SPEED_TRACKS:
            out[job][label]["warm_s"] = round(float(np.median(times[label])), 2)
        print(job, out[job], flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sections", default="fit,time")
    ap.add_argument("--iterations", type=int, default=6000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results"
                                         / "end_network.json"))
    a = ap.parse_args()
    out = pathlib.Path(a.out)
    result = json.loads(out.read_text()) if out.exists() else {}
    if "fit" in a.sections:
        t0 = time.perf_counter()
        x, e_max, e_med, at = fit(a.iterations, a.seed)
        result = {"n_aux": ends.N_AUX, "seed": a.seed, "iterations": a.iterations,
                  "hf_weight": ends.HF_WEIGHT, "fit_s": round(time.perf_counter() - t0, 1),
                  "fit_max_rel_err_10_2500_Hz": e_max, "fit_max_at_Hz": at,
                  "fit_median_rel_err_10_2500_Hz": e_med,
                  "fit_beside_edge_max_rel_err": ends.fit_error(wf.Track.comparison(), x)}
        print(result, flush=True)
        result["receptance"] = receptance_errors(x)
        result["factors"] = np.asarray(x).tolist()  # L_K, L_C, L_M stacked (ends.matrices)
        out.write_text(json.dumps(result, indent=1))
    if "edge" in a.sections:
        result["edge"] = edge_figures()
        print(result["edge"], flush=True)
        out.write_text(json.dumps(result, indent=1))
    if "warm" in a.sections:
        result["warm"] = warm()
        out.write_text(json.dumps(result, indent=1))
    if "speed" in a.sections:
        result["speed"] = speed()
        out.write_text(json.dumps(result, indent=1))
    if "time" in a.sections:
        result["time_domain"] = time_domain()
        out.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()

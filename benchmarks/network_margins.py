"""How close wheels, sensors and a detector may come to end networks (``Track.ends``;
issue 33, "fewer bays where physics allows"): the guards' margins for tracks whose ends
reflect nothing, derived as the clamped ends' were (``docs/convergence.md``, "Physics
guards"), against 70 bays with end networks.

Wheels: a new flat 0.9 mm at 20, 40, 120 and 200 km/h, 5 impact positions, Hertz-trajectory,
the default settings, on a track lengthened from 4 bays to keep the paths ``f / beta`` from
the ends (``guards.NETWORK_END_FACTOR = f``): the largest max-force difference [%] and
min-force difference [kN] per f, and the bays.

Detector: the same flat at 40, 120 and 200 km/h, 5 positions, with the 3-bay detector (the
reading's settings), on a track lengthened from 4 bays to keep every bridge ``f / beta``
from the ends (``guards.NETWORK_SENSOR_END_FACTOR = f``, no least length:
``wfjax.params.NETWORK_READING_BAYS = 4``): the largest reading difference [%] per f, the bays and
the modes.

Sensors: seat force on the impact bay's two sleepers (0.01 and 0.64 m) and shear at its
gauges (0.1 and 0.55 m), the same runs without a detector, per sensor margin factor: the
largest difference [%] of each quantity's max per run. The detector and sensor sections
keep the wheels' margin at ``WHEEL_CHOSEN``.

Run: ``python benchmarks/network_margins.py`` (about 5 minutes on 2 cores); writes
``benchmarks/results/network_margins.json``.
"""

from __future__ import annotations

import json
import pathlib
import time

import numpy as np

import wfjax as wf
from wfjax.scenario import guards

FLAT = wf.Flat.new(0.9e-3)
WHEEL_FACTORS = (0.25, 0.5, 1.0, 2.0, 3.0)
SENSOR_FACTORS = (0.5, 1.0, 2.0, 3.0, 4.0, 8.5)
WHEEL_CHOSEN = 0.5  # guards.NETWORK_END_FACTOR: the wheels' margin in the sections after


def _track(n_bays: int) -> wf.Track:
    return wf.Track.comparison(n_bays=n_bays, ends="network")


def _sweep(track, speeds_kmh, detector=None, **kw):
    cfg = wf.SimConfig(allow_inaccurate=True)  # the margins measured are what guards refuse
    return wf.sweep(FLAT, np.asarray(speeds_kmh) / 3.6, 5, contact="hertz-trajectory",
                    track=track, config=cfg, detector=detector, progress=False, **kw)


def wheels() -> dict:
    """Max / min force differences from 70 bays per wheel-path margin factor."""
    speeds = [20.0, 40.0, 120.0, 200.0]
    ref = _sweep(_track(70), speeds)
    out = {}
    for f in WHEEL_FACTORS:
        guards.NETWORK_END_FACTOR = f
        r = _sweep(_track(4), speeds)
        out[f"{f:g}"] = {
            "n_bays": r.settings["n_bays"], "n_modes": r.settings["n_modes"],
            "max_force_pct": round(100 * float(np.max(np.abs(
                np.asarray(r.max_force) / np.asarray(ref.max_force) - 1))), 4),
            "min_force_kN": round(float(np.max(np.abs(
                np.asarray(r.min_force) - np.asarray(ref.min_force)))) / 1e3, 4)}
        print("wheels", f, out[f"{f:g}"], flush=True)
    return out


def detector() -> dict:
    """Reading differences from 70 bays per sensor margin factor (no least length)."""
    speeds, det = [40.0, 120.0, 200.0], wf.Detector()
    guards.NETWORK_END_FACTOR = WHEEL_CHOSEN
    ref = _sweep(_track(70), speeds, det)
    wf.params.NETWORK_READING_BAYS = 4
    out = {}
    for f in SENSOR_FACTORS:
        guards.NETWORK_SENSOR_END_FACTOR = f
        r = _sweep(_track(4), speeds, det)
        a, b = np.asarray(r.detector_peak), np.asarray(ref.detector_peak)
        out[f"{f:g}"] = {"n_bays": r.settings["n_bays"], "n_modes": r.settings["n_modes"],
                         "reading_pct": round(100 * float(np.max(np.abs(a / b - 1))), 4)}
        print("detector", f, out[f"{f:g}"], flush=True)
    return out


def sensors() -> dict:
    """Seat force and shear differences [%] from 70 bays (largest over runs of each
    quantity's max) per sensor margin factor, sensors on the impact bay's sleepers."""
    speeds, x = [40.0, 120.0, 200.0], [0.01, 0.1, 0.55, 0.64]
    kw = {"sensors": x, "sensor_quantities": ("seat_force", "shear")}
    guards.NETWORK_END_FACTOR = WHEEL_CHOSEN
    ref = _sweep(_track(70), speeds, **kw)
    out = {}
    for f in SENSOR_FACTORS:
        guards.NETWORK_SENSOR_END_FACTOR = f
        r = _sweep(_track(4), speeds, **kw)
        a, b = np.asarray(r.sensor_max), np.asarray(ref.sensor_max)  # [.., quantity, sensor]
        e = np.abs(a / b - 1).reshape(-1, 2, len(x)).max(axis=0)  # [quantity, sensor]
        out[f"{f:g}"] = {"n_bays": r.settings["n_bays"],
                         "seat_force_pct": round(100 * float(e[0, [0, 3]].max()), 4),
                         "shear_pct": round(100 * float(e[1, [1, 2]].max()), 4)}
        print("sensors", f, out[f"{f:g}"], flush=True)
    return out


def main() -> None:
    t0 = time.perf_counter()
    out = {"wheels": wheels(), "detector": detector(), "sensors": sensors()}
    out["seconds"] = round(time.perf_counter() - t0, 1)
    path = pathlib.Path(__file__).parent / "results" / "network_margins.json"
    path.write_text(json.dumps(out, indent=1))
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()

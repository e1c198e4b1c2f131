"""Convergence of the sensors' dynamic histories (issue 14): seat force, rail shear and the
detector reading of a flat impact under time-step and track-mode refinement.

Run: ``python benchmarks/bench_sensor_convergence.py``. Rounded 0.9 mm / 100 mm flat,
100 km/h, Hertz-trajectory contact, impact at 0.3 m (mid-bay between the sleepers at 0 and
0.65 m); sensors at 0.65 m (shear 5 cm past that sleeper and its seat force: sensor at
0.7 m) and the 3-bay detector. Each history is compared with the finest run on the
reference's time grid (linear interpolation): max of the seat force, max |difference| / max
of the reference (for the shear, away from the +-3 mm where the wheel passes the sensor
and the shear jumps by F). Prints Markdown (the table of docs/convergence.md).
"""

from __future__ import annotations

import numpy as np

import wfjax as wf
from wfjax.scenario.sensors import Detector

FLAT = wf.Flat.rounded(0.9e-3, 0.1)
V = 100 / 3.6
SENSORS = [0.7]
RUNS = {  # label -> (max_travel_step [m], max_time_step [s], track_max_frequency [Hz])
    "1 mm, 25 us, 10 kHz (default)": (1e-3, 25e-6, 10e3),
    "0.5 mm, 12.5 us, 10 kHz": (0.5e-3, 12.5e-6, 10e3),
    "0.25 mm, 6.25 us, 10 kHz": (0.25e-3, 6.25e-6, 10e3),
    "1 mm, 25 us, 5 kHz": (1e-3, 25e-6, 5e3),
    "1 mm, 25 us, 15 kHz": (1e-3, 25e-6, 15e3),
    "1 mm, 25 us, 20 kHz": (1e-3, 25e-6, 20e3),
    "1 mm, 25 us, all 1187 modes": (1e-3, 25e-6, 1e6),
    "0.25 mm, 6.25 us, 20 kHz (reference)": (0.25e-3, 6.25e-6, 20e3),
}


def run(travel, step, fmax):
    cfg = wf.SimConfig(max_travel_step=travel, max_time_step=step, track_max_frequency=fmax)
    r = wf.simulate(FLAT, V, contact="hertz-trajectory", impact_position=0.3, config=cfg,
                    sensors=SENSORS, detector=Detector())
    s = np.asarray(r.s)
    return s, {"seat": np.asarray(r.sensors["seat_force"])[:, 0],
               "shear": np.asarray(r.sensors["shear"])[:, 0],
               "sleeper_acc": np.asarray(r.sensors["sleeper_acc"])[:, 0],
               "reading": float(np.max(r.detector_peak)), "force": float(r.max_force)}


def main() -> None:
    out = {k: run(*v) for k, v in RUNS.items()}
    s_ref, ref = out["0.25 mm, 6.25 us, 20 kHz (reference)"]
    print("| run | max seat force [kN] | seat force history | shear history "
          "| sleeper acc. history | detector reading [kN] | max contact force [kN] |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for label, (s, h) in out.items():
        errs = []
        # the shear jumps by F as the wheel passes the sensor: leave out +-3 mm around it
        away = np.abs(s_ref + 0.3 - SENSORS[0]) > 3e-3
        for key in ("seat", "shear", "sleeper_acc"):
            diff = np.where(away, np.interp(s_ref, s, h[key]) - ref[key], 0.0)
            errs.append(f"{100 * np.max(np.abs(diff)) / np.max(np.abs(ref[key])):.2f} %")
        print(f"| {label} | {np.max(h['seat']) / 1e3:.2f} | {' | '.join(errs)} | "
              f"{h['reading'] / 1e3:.2f} | {h['force'] / 1e3:.2f} |")


if __name__ == "__main__":
    main()

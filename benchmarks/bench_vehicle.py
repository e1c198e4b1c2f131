"""Several wheels on one rail (issue 17): speed, memory and convergence of the coupled loop.

Run: ``python benchmarks/bench_vehicle.py [--repeats N] [--convergence] [--memory]``.

* Speed (default): the default ``wfjax sweep`` (rounded 0.9 mm/100 mm and new 0.9 mm flats,
  20-300 km/h in 10 km/h steps, 10 positions, 3D contact) with one wheel, the two-axle bogie
  (2.5 m) and eight wheels (2.5 m apart), each compiled by a first call and then timed ``N``
  times interleaved (the ratio of medians is reported; the goal is at most 2x and 6x the
  one-wheel warm time).
* ``--memory``: the peak resident memory [GiB] of a fresh process running the eight-wheel
  sweep (goal: under 2 GiB).
* ``--convergence``: the bogie's trailing (smooth) wheel behind a rounded 0.9 mm flat at
  100 km/h (Hertz, profile input) under time-step and mode-truncation refinement: its max
  and min force and the largest difference of its force history from the finest run.

Prints Markdown.
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys

import numpy as np
from _timing import interleaved_sweeps, print_ratios

import wfjax as wf
from wfjax.model.vehicle import Vehicle

VEHICLES = {"1 wheel": None, "bogie (2 wheels, 2.5 m)": Vehicle.bogie(),
            "8 wheels, 2.5 m apart": Vehicle(tuple(2.5 * np.arange(8)))}


def speed(repeats: int) -> None:
    variants = {name: {"vehicle": vehicle} for name, vehicle in VEHICLES.items()}
    print_ratios(interleaved_sweeps(variants, repeats), "1 wheel", "vehicle")


def memory() -> None:
    code = ("import numpy as np, wfjax as wf; from wfjax.model.vehicle import Vehicle; "
            "wf.sweep([wf.Flat.rounded(0.9e-3, 0.1), wf.Flat.new(0.9e-3)], "
            "np.arange(20.0, 300.1, 10.0) / 3.6, 10, progress=False, "
            "vehicle=Vehicle(tuple(2.5 * np.arange(8))))")
    subprocess.run([sys.executable, "-c", code], check=True)
    peak_kib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    print(f"peak resident memory of the eight-wheel default sweep: {peak_kib / 2**20:.2f} GiB")


def convergence() -> None:
    flat = wf.Flat.rounded(0.9e-3, 0.1)
    v = 100 / 3.6
    runs = {}
    for label, cfg in {
        "25 us / 1 mm, 10 kHz (default)": wf.SimConfig(),
        "12.5 us / 0.5 mm, 10 kHz": wf.SimConfig(max_time_step=12.5e-6, max_travel_step=5e-4),
        "6.25 us / 0.25 mm, 10 kHz": wf.SimConfig(max_time_step=6.25e-6,
                                                  max_travel_step=2.5e-4),
        "25 us / 1 mm, 20 kHz": wf.SimConfig(track_max_frequency=20e3),
        "25 us / 1 mm, 40 kHz (all modes)": wf.SimConfig(track_max_frequency=40e3),
    }.items():
        res = wf.simulate(flat, v, contact="hertz-profile", impact_position=0.1,
                          vehicle=Vehicle.bogie(), config=cfg)
        runs[label] = res
    print("| run | trailing max [kN] | trailing min [kN] | max history diff. [kN] | "
          "flat wheel max [kN] |")
    print("| --- | --- | --- | --- | --- |")
    for group in (list(runs)[:3], [list(runs)[0], *list(runs)[3:]]):
        finest = runs[group[-1]]
        for label in group:
            res = runs[label]
            f = np.interp(np.asarray(finest.t), np.asarray(res.t),
                          np.asarray(res.wheel_force)[:, 1])
            diff = np.max(np.abs(f - np.asarray(finest.wheel_force)[:, 1])) / 1e3
            print(f"| {label} | {float(res.wheel_max_force[1]) / 1e3:.2f} | "
                  f"{float(res.wheel_min_force[1]) / 1e3:.2f} | {diff:.2f} | "
                  f"{float(res.wheel_max_force[0]) / 1e3:.2f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--convergence", action="store_true")
    parser.add_argument("--memory", action="store_true")
    args = parser.parse_args()
    if args.convergence:
        convergence()
    elif args.memory:
        memory()
    else:
        speed(args.repeats)


if __name__ == "__main__":
    main()

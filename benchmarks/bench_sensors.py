"""Cost of sensors and the detector on the default sweep (issue 14: eight sensors add at most
30 % to its warm time).

Run: ``python benchmarks/bench_sensors.py [--repeats N]``. The default ``wfjax sweep`` (rounded
0.9 mm/100 mm and new 0.9 mm flats, 20-300 km/h in 10 km/h steps, 10 positions, 3D contact)
without sensors and with eight sensors computing every quantity of
:data:`wfjax.scenario.sensors.QUANTITIES`, two of them or one (``--detector``: also the 3-bay
detector alone). Each variant is compiled by a first call, then timed ``N``
times interleaved with the others (the machine is shared: the ratio of medians is reported).
Prints Markdown.
"""

from __future__ import annotations

import argparse

from _timing import interleaved_sweeps, print_ratios

from wfjax.scenario.sensors import Detector

SENSORS = [-0.65, -0.325, 0.0, 0.1, 0.325, 0.55, 0.65, 0.975]  # m: 8 sensors


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--detector", action="store_true",
                        help="also time the 3-bay detector (its longer windows dominate)")
    args = parser.parse_args()
    variants = {"no sensors": {}, "8 sensors x 9 quantities": {"sensors": SENSORS},
                "8 sensors x (shear, seat_force)": {
                    "sensors": SENSORS, "sensor_quantities": ("shear", "seat_force")},
                "8 sensors x shear": {"sensors": SENSORS, "sensor_quantities": ("shear",)}}
    if args.detector:
        variants["detector (3 bays)"] = {"detector": Detector()}
    print_ratios(interleaved_sweeps(variants, args.repeats), "no sensors")


if __name__ == "__main__":
    main()

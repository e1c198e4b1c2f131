"""``wfjax detector``: what a wheel impact load detector reads, against the true peak contact
force, over speed and impact position (and the extremes at fixed rail sensors).

One :func:`wfjax.sweep` with ``detector=`` and ``sensors=``: writes ``detector.csv`` (one row
per speed x impact position x bay), ``sensors.csv`` (extremes of every sensor quantity),
``detector.json`` and ``detector.png`` (reading against true peak force). The flat strikes once
per revolution (``Vehicle.repeat_flats``): a detector reaching more than a circumference past
the impact bay reads its next strike too.
"""

from __future__ import annotations

import csv
import io
import time

import numpy as np

from ._common import (
    check_finite,
    prepare_out,
    resolve_case,
    save_figure,
    sensor_positions,
    write_atomic,
    write_summary,
)

HELP = "detector readings (crib shear over N bays) vs true peak contact force (CSV, JSON, PNG)"

def _csv(result) -> str:
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["speed_kmh", "impact_position_mm", "bay", "detector_peak_kN",
                "detector_ratio", "true_max_force_kN"])
    for j, v in enumerate(np.asarray(result.speeds)):
        for k, p in enumerate(np.asarray(result.impact_positions)):
            for b, bay in enumerate(result.detector_bays):
                w.writerow([f"{v * 3.6:.6g}", f"{p * 1e3:.6g}", int(bay),
                            f"{result.detector_peak[0, j, k, b] / 1e3:.6f}",
                            f"{result.detector_ratio[0, j, k, b]:.6f}",
                            f"{result.max_force[0, j, k] / 1e3:.6f}"])
    return buf.getvalue()


def write_passage(case) -> int:
    """``--passage-csv FILE``: a passage of the train ``passage.train`` with the flats
    ``passage.flats`` over the case's detector, simulated in full
    (:func:`wfjax.identify.synthetic.simulate_passage`), written as a readings CSV for
    ``wfjax identify`` (docs/identify.md); the truth goes to FILE's ``.truth.json``."""
    import json
    from pathlib import Path

    from ..commands.identify import LAYOUTS
    from ..identify.passage import passages_csv
    from ..identify.synthetic import parse_flats, simulate_passage
    from ..scenario.sensors import Detector

    layout = LAYOUTS[case.get("passage.train") or "wagon"]
    flats = parse_flats(case.get("passage.flats") or "")
    detector = Detector(case["detector.n_bays"], case["detector.first_bay"],
                        case["detector.gauge_offset"], case["detector.calibration"])
    wheel, track, _, _ = case.model()
    detector.gauges(float(track.sleeper_spacing))
    if any(f.wheel >= len(layout) for f in flats):
        raise ValueError(f"--train-flats: a wheel index beyond the train's {len(layout)} "
                         f"wheels (0..{len(layout) - 1})")
    speed = (case.get("passage.speed_kmh") or 100.0) / 3.6
    path = Path(case["passage.csv"])
    print(f"wfjax detector: a passage of {len(layout)} wheels at {speed * 3.6:.0f} km/h over "
          f"{detector.n_bays} bays from bay {detector.first_bay}, "
          f"{case.get('passage.contact') or 'hertz-trajectory'} contact")
    noise = case.get("passage.noise")
    passage, truth = simulate_passage(
        layout, flats, speed, detector, noise=0.03 if noise is None else noise,
        seed=case.get("passage.seed") or 0, wheel=wheel,
        contact=case.get("passage.contact") or "hertz-trajectory")
    if path.parent and not path.parent.exists():
        path.parent.mkdir(parents=True)
    write_atomic(path, passages_csv([passage]))
    write_atomic(path.with_suffix(".truth.json"), json.dumps(truth, indent=2) + "\n")
    print(f"  wrote {path} and {path.with_suffix('.truth.json')}")
    return 0


def run(args) -> int:
    case = resolve_case(args, "detector")
    if case.get("passage.csv"):
        return write_passage(case)
    from ..model.vehicle import Vehicle
    from ..plotting import detector_figure
    from ..scenario.sensors import Detector
    from ..sweeps import sweep

    speeds = case.speeds()
    flat = case.flat()
    wheel, track, material, config = case.model()
    sensors = sensor_positions(case, track)  # errors before work
    detector = Detector(case["detector.n_bays"], case["detector.first_bay"],
                        case["detector.gauge_offset"], case["detector.calibration"])
    detector.gauges(float(track.sleeper_spacing))  # bad gauge offset: error before work
    contact = case["run.contact"]
    from ..outsize import check_detector

    check_detector(case, speeds.size, len(sensors or ()))
    out = prepare_out(args.out)
    print(f"wfjax detector: {speeds.size} speeds x {case['run.impact_positions']} positions, "
          f"{detector.n_bays} bays from bay {detector.first_bay}, {contact} contact")
    t0 = time.perf_counter()
    result = sweep(flat, speeds, case["run.impact_positions"], contact=contact, wheel=wheel,
                   track=track, material=material, config=config, sensors=sensors,
                   detector=detector, vehicle=Vehicle((0.0,), repeat_flats=True))
    result = result._replace(detector_peak=result.detector_peak[..., 0, :],  # one wheel
                             detector_ratio=result.detector_ratio[..., 0, :])
    elapsed = time.perf_counter() - t0
    check_finite("detector", max_force=result.max_force, detector_peak=result.detector_peak,
                 sensor_max=result.sensor_max)
    write_atomic(out / "detector.csv", _csv(result))
    write_atomic(out / "sensors.csv", result.sensors_to_csv())
    reading = result.detector_peak[0].max(axis=-1)  # [speeds, positions]: max over bays
    ratio = reading / result.max_force[0]
    summary = {"flat": result.flats[0], "contact": contact, "bays": detector.n_bays,
               "first_bay": detector.first_bay, "gauge_offset_m": detector.gauge_offset,
               "calibration": detector.calibration, "sensors_m": sensors,
               "max_reading_kN": float(reading.max()) / 1e3,
               "max_true_force_kN": float(result.max_force.max()) / 1e3,
               "reading_over_true_peak": {"min": float(ratio.min()),
                                          "max": float(ratio.max()),
                                          "mean": float(ratio.mean())},
               "settings": result.settings, "wall_time_s": elapsed}
    write_summary(out / "detector.json", summary, case,
                  {"profile_csv": case.get("flat.profile_csv")})
    save_figure(detector_figure(result), out / "detector.png")
    print(f"  max reading {summary['max_reading_kN']:.1f} kN, max true peak "
          f"{summary['max_true_force_kN']:.1f} kN; reading / true peak "
          f"{ratio.min():.2f}-{ratio.max():.2f} over speeds and positions")
    print(f"  {elapsed:.1f} s; wrote {out}/detector.csv, sensors.csv, detector.json, "
          "detector.png, case.toml")
    return 0

"""``wfjax simulate``: one run, the contact force history of a flat at one speed."""

from __future__ import annotations

import numpy as np

from ..outsize import check_simulate
from ._common import (
    case_vehicle,
    check_finite,
    prepare_out,
    resolve_case,
    save_figure,
    sensor_positions,
    write_atomic,
    write_summary,
)

HELP = "contact force history of one wheel-flat passage (CSV, JSON, PNG)"

def run(args) -> int:
    case = resolve_case(args, "simulate")
    from ..api import simulate
    from ..plotting import force_history_figure, vehicle_history_figure

    flat = case.flat()
    wheel, track, material, config = case.model()
    track = case.supports(track)
    rail_rough, wheel_rough = case.roughness(float(wheel.radius))
    from ..scenario.measured import case_wheel_roughness  # a flat.sections measurement's

    wheel_rough = case_wheel_roughness(case, wheel_rough)
    contact, speed_kmh = case["run.contact"], case["run.speed_kmh"]
    sensors = sensor_positions(case, track)
    vehicle = case_vehicle(case, wheel)
    hanging = np.size(case.get("supports.void_sleepers") or []) \
        if case.get("supports.void_gap", 0.0) > 0 else 0
    check_simulate(case, flat, config, len(sensors or ()),
                   1 if vehicle is None else vehicle.n_wheels, hanging)
    out = prepare_out(args.out)
    result = simulate(flat, speed_kmh / 3.6, contact=contact,
                      impact_position=case["run.impact_position"], wheel=wheel, track=track,
                      material=material, config=config, sensors=sensors, vehicle=vehicle,
                      roughness=rail_rough, wheel_roughness=wheel_rough)
    check_finite("simulate", force=result.force, wheel_disp=result.wheel_disp,
                 rail_disp=result.rail_disp)
    write_atomic(out / "simulate.csv", result.to_csv())
    if sensors is not None:
        write_atomic(out / "sensors.csv", result.sensors_to_csv())
    summary = {"flat": flat.kind, "depth_mm": float(flat.depth) * 1e3, "contact": contact,
               **result.summary()}
    if flat.kind == "rounded":
        summary["length_mm"] = float(flat.length) * 1e3
    write_summary(out / "simulate.json", summary, case,
                  {k: case.get(k) for k in ("flat.profile_csv", "flat.sections",
                                            "roughness.rail_csv", "roughness.wheel_csv")})
    if vehicle is None:
        figure = force_history_figure(result, flat, float(wheel.preload))
    else:
        figure = vehicle_history_figure(result, vehicle, float(wheel.preload))
    save_figure(figure, out / "simulate.png")
    loss = (f"loss of contact for {summary['loss_of_contact_duration_ms']:.2f} ms"
            if summary["loss_of_contact"] else "no loss of contact")
    print(f"{flat.kind} flat d = {summary['depth_mm']:g} mm at {speed_kmh:g} km/h ({contact}):"
          f" max {summary['max_force_kN']:.1f} kN, min {summary['min_force_kN']:.1f} kN, {loss}")
    for w in summary.get("wheels", []):
        print(f"  wheel {w['wheel']} ({vehicle.positions[w['wheel']]:g} m behind the leading): "
              f"max {w['max_force_kN']:.1f} kN, min {w['min_force_kN']:.1f} kN, axle-box "
              f"acceleration up to {w['axle_box_acceleration_peak_m_s2']:.0f} m/s^2")
    for h in summary.get("hanging_sleepers", []):
        print(f"  hanging sleeper {h['sleeper']}: ballast force up to "
              f"{h['max_support_force_kN']:.1f} kN, gap open {h['open_ms']:.1f} ms, sleeper "
              f"down by up to {h['max_sleeper_disp_mm']:.2f} mm")
    print(f"wrote {out}/simulate.csv, simulate.json, simulate.png, case.toml")
    return 0

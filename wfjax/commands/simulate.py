"""``wfjax simulate``: one run, the contact force history of a flat at one speed."""

from __future__ import annotations

from ._common import (
    ROUGHNESS_FLAGS,
    VEHICLE_FLAGS,
    add_case_arguments,
    add_out_argument,
    add_roughness_arguments,
    add_vehicle_arguments,
    case_vehicle,
    check_finite,
    prepare_out,
    resolve_case,
    save_figure,
    sensor_positions,
    write_atomic,
    write_summary,
)
from .geometry import add_flat_arguments
from .sweep import FLAT_FLAGS, MODEL_FLAGS, add_model_arguments, add_profile_arguments

HELP = "contact force history of one wheel-flat passage (CSV, JSON, PNG)"

FLAGS = {**MODEL_FLAGS, **FLAT_FLAGS, "speed_kmh": ("run.speed_kmh", 1.0),
         "impact_position_mm": ("run.impact_position", 1e-3), "sensors_m": ("run.sensors", 1.0),
         **VEHICLE_FLAGS, **ROUGHNESS_FLAGS}


def add_arguments(parser) -> None:
    add_flat_arguments(parser)
    add_profile_arguments(parser)
    parser.add_argument("--speed-kmh", type=float, help="train speed (default 100)")
    parser.add_argument("--impact-position-mm", type=float,
                        help="impact position from a sleeper centre in mm, [0, 650) (default 0); "
                             "on a track whose supports vary an absolute rail coordinate "
                             "(x = 0 above the middle sleeper)")
    parser.add_argument("--sensors-m",
                        help="rail sensor positions in m, 'x1,x2,...' (x = 0 at a sleeper): "
                             "their histories go to sensors.csv (docs/detector.md)")
    add_vehicle_arguments(parser)
    add_roughness_arguments(parser, monte_carlo=False)
    add_model_arguments(parser)
    add_case_arguments(parser)
    add_out_argument(parser, "out/simulate")


def run(args) -> int:
    case = resolve_case(args, "simulate", FLAGS)
    from ..api import simulate
    from ..plotting import force_history_figure, vehicle_history_figure

    flat = case.flat()
    wheel, track, material, config = case.model()
    track = case.supports(track)
    rail_rough, wheel_rough = case.roughness(float(wheel.radius))
    contact, speed_kmh = case["run.contact"], case["run.speed_kmh"]
    sensors = sensor_positions(case, track)
    vehicle = case_vehicle(case, wheel)
    result = simulate(flat, speed_kmh / 3.6, contact=contact,
                      impact_position=case["run.impact_position"], wheel=wheel, track=track,
                      material=material, config=config, sensors=sensors, vehicle=vehicle,
                      roughness=rail_rough, wheel_roughness=wheel_rough)
    check_finite("simulate", force=result.force, wheel_disp=result.wheel_disp,
                 rail_disp=result.rail_disp)
    out = prepare_out(args.out)
    write_atomic(out / "simulate.csv", result.to_csv())
    if sensors is not None:
        write_atomic(out / "sensors.csv", result.sensors_to_csv())
    summary = {"flat": flat.kind, "depth_mm": float(flat.depth) * 1e3, "contact": contact,
               **result.summary()}
    if flat.kind == "rounded":
        summary["length_mm"] = float(flat.length) * 1e3
    write_summary(out / "simulate.json", summary, case,
                  {k: case.get(k) for k in ("flat.profile_csv", "roughness.rail_csv",
                                            "roughness.wheel_csv")})
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

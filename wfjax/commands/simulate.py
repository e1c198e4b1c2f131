"""``wfjax simulate``: one run, the contact force history of a flat at one speed."""

from __future__ import annotations

from ..interaction import simulate
from ._common import add_out_argument, prepare_out, save_figure, write_atomic, write_json
from .geometry import add_flat_arguments, flat_from_args
from .sweep import add_model_arguments, model_from_args

HELP = "contact force history of one wheel-flat passage (CSV, JSON, PNG)"


def add_arguments(parser) -> None:
    add_flat_arguments(parser)
    parser.add_argument("--speed-kmh", type=float, default=100.0, help="train speed (100)")
    parser.add_argument("--impact-position-mm", type=float, default=0.0,
                        help="impact position from a sleeper centre in mm, [0, 650) (default 0)")
    add_model_arguments(parser)
    add_out_argument(parser, "out/simulate")


def run(args) -> int:
    from ..plotting import force_history_figure

    flat = flat_from_args(args)
    wheel, track, material, config = model_from_args(args)
    if not 0 < args.speed_kmh <= 540:
        raise ValueError(f"--speed-kmh must be in (0, 540], got {args.speed_kmh}")
    result = simulate(flat, args.speed_kmh / 3.6, contact=args.contact,
                      impact_position=args.impact_position_mm * 1e-3, wheel=wheel,
                      track=track, material=material, config=config)
    out = prepare_out(args.out)
    write_atomic(out / "simulate.csv", result.to_csv())
    summary = {"flat": flat.kind, "depth_mm": args.depth_mm, "contact": args.contact,
               **result.summary()}
    if flat.kind == "rounded":
        summary["length_mm"] = args.length_mm
    write_json(out / "simulate.json", summary)
    save_figure(force_history_figure(result, flat, float(wheel.preload)), out / "simulate.png")
    loss = (f"loss of contact for {summary['loss_of_contact_duration_ms']:.2f} ms"
            if summary["loss_of_contact"] else "no loss of contact")
    print(f"{flat.kind} flat d = {args.depth_mm:g} mm at {args.speed_kmh:g} km/h ({args.contact}):"
          f" max {summary['max_force_kN']:.1f} kN, min {summary['min_force_kN']:.1f} kN, {loss}")
    print(f"wrote {out}/simulate.csv, simulate.json, simulate.png")
    return 0

"""How a round wheel's neighbour correction moves with the neighbour's impact coordinate
(issue 31, docs/identify.md "Every strike"): the identification's correction runs
(:func:`wfjax.identify.forward.coupled_batch`, every strike, the identification's track and
roughness) of a study wagon's bogie with the round wheel round and its neighbour's true
flat struck at its true impact coordinate + dx, minus the round wheel alone, per detector
bay, for dx over +-``--span`` m.

    python benchmarks/identify_neighbour_phase.py --wagon 21 --wheel 2 --neighbour 3 \
        --passages DIR

``--wagon`` is the study's wagon index from 0 (the study prints it from 1), its passages
read from the study's ``--passages`` folder (seed 41, site seed 31, 60/100/140 km/h).
Writes ``benchmarks/results/identify_neighbour_phase.json``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from identify_study import kept_passages  # benchmarks/, the script's folder

ROOT = Path(__file__).resolve().parents[1]


def scan(passages, truths, wheel: int, neighbour: int, dx: np.ndarray) -> list[dict]:
    """Per passage the round ``wheel``'s correction [kN] per bay at each offset ``dx`` [m] of
    the ``neighbour``'s impact coordinate from its truth (one bogie of the wagon)."""
    from wfjax.identify import forward as fwd
    from wfjax.identify.pipeline import correction_roughness
    from wfjax.params import Wheel

    radius = float(Wheel().radius)
    rough = correction_roughness()  # identify()'s, seed 0
    smooth = fwd.round_wheel(radius)
    pair = sorted((wheel, neighbour))
    layout = np.asarray(passages[0].positions)[pair] - passages[0].positions[pair[0]]
    out = []
    for p, truth in zip(passages, truths, strict=True):
        t = truth[neighbour]
        flat = fwd.flat_of(t["kind"], t["length"], t.get("factor") or 1.0, radius)
        groups = [([smooth if j == wheel else flat for j in pair],
                   [truth[j]["impact"] + (d if j == neighbour else 0.0) for j in pair])
                  for d in dx]
        both, _ = fwd.coupled_batch(groups, layout, p.speed, p.detector(), roughness=rough)
        alone, _ = fwd.coupled_batch([([smooth], [0.3])], [0.0], p.speed, p.detector(),
                                     roughness=rough)
        c = (both[:, pair.index(wheel)] - alone[0, 0]) / 1e3
        out.append({"speed_kmh": round(p.speed * 3.6, 3), "impact_m": t["impact"],
                    "dx_m": dx.round(4).tolist(), "correction_kN": c.round(2).tolist()})
        print(f"{p.speed * 3.6:.0f} km/h, the neighbour's impact {t['impact']:.3f} m:")
        for d, row in zip(dx, c, strict=True):
            print(f"  {d:+.2f} m", np.round(row, 1))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--wagon", type=int, default=21)
    ap.add_argument("--wheel", type=int, default=2, help="the round wheel")
    ap.add_argument("--neighbour", type=int, default=3, help="its flat neighbour")
    ap.add_argument("--span", type=float, default=0.16)
    ap.add_argument("--passages", required=True, metavar="DIR")
    args = ap.parse_args()
    passages, truths = kept_passages(args.passages, args.wagon)
    dx = np.arange(-args.span, args.span + 1e-9, 0.02)
    rows = scan(passages, truths, args.wheel, args.neighbour, dx)
    out = ROOT / "benchmarks" / "results" / "identify_neighbour_phase.json"
    out.write_text(json.dumps({"wagon": args.wagon, "wheel": args.wheel,
                               "neighbour": args.neighbour, "passages": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()

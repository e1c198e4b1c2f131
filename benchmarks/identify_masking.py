"""Each flat of a study wagon alone (issue 31, docs/identify.md "A long flat masked by its
neighbour"): the wagon of ``benchmarks/identify_study.py`` re-simulated noise-free with
the same impacts, site and contact law, once per flat with the other wheels round and once
with every flat, so a wheel's reading can be split into its own flat's and its bogie
partner's ringing.

    python benchmarks/identify_masking.py --seed 43 --truth-contact 3d --wagon 22

``--wagon`` counts from 1 as the docs do (the results' ``wagon`` field + 1). Prints, per
passage and flat wheel, its readings [kN] in the bay where the full truth reads it most;
writes ``--out`` (JSON, default ``benchmarks/results/identify_masking.json``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from identify_study import WAGON, draw_wagon, speeds  # benchmarks/, the script's folder

ROOT = Path(__file__).resolve().parents[1]


def wagon_draw(k: int, seed: int, sites: int):
    """(flats, site) of study wagon ``k`` (from 0), drawn as ``identify_study.run`` draws."""
    rng = np.random.default_rng(seed)
    for _ in range(k):
        draw_wagon(rng, sites)
    return draw_wagon(rng, sites)


def split(args) -> list[dict]:
    """Per passage: {speed_kmh, flat wheels, readings [kN] per variant ("all", "only i")}."""
    from wfjax.identify.synthetic import simulate_passage
    from wfjax.scenario.sensors import Detector

    k = args.wagon - 1
    flats, site = wagon_draw(k, args.seed, args.sites)
    out = []
    for j, v in enumerate(speeds(args)):
        seed = args.seed * 100003 + 101 * k + j + 1  # identify_study.simulate_wagon's
        runs = {"all": flats} | {f"only {f.wheel}": [f] for f in flats}
        got = {}
        for name, chosen in runs.items():
            p, _ = simulate_passage(WAGON, chosen, v / 3.6, Detector(5, -1), noise=0.0,
                                    seed=seed, site_seed=args.site_seed * 1009 + site,
                                    contact=args.truth_contact)
            got[name] = (p.readings / 1e3).tolist()
        out.append({"speed_kmh": v, "flat_wheels": [f.wheel for f in flats],
                    "readings_kN": got})
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--wagon", type=int, required=True, help="study wagon (from 1)")
    ap.add_argument("--seed", type=int, default=41)
    ap.add_argument("--site-seed", type=int, default=31)
    ap.add_argument("--sites", type=int, default=4)
    ap.add_argument("--speeds-kmh", default="60,100,140")
    ap.add_argument("--truth-contact", default="hertz-trajectory")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/identify_masking.json"))
    args = ap.parse_args(argv)
    from wfjax.cli import enable_compilation_cache

    enable_compilation_cache()
    rows = split(args)
    for r in rows:
        full = np.asarray(r["readings_kN"]["all"])
        for w in r["flat_wheels"]:
            b = int(np.argmax(full[w]))
            parts = ", ".join(f"{name} {np.asarray(x)[w, b]:.1f}"
                              for name, x in r["readings_kN"].items())
            print(f"{r['speed_kmh']:.0f} km/h, wheel {w}, bay {b} (from 0): {parts} kN")
    Path(args.out).write_text(json.dumps({"argv": vars(args), "passages": rows}, indent=1))


if __name__ == "__main__":
    main()

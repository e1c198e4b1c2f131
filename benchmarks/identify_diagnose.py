"""Chosen wagons of ``benchmarks/identify_study.py`` case by case (issue 31): every wheel's truth,
each passage's impact (inside a gauge's gate or not), the identification with the neighbour
correction at the neighbours' most probable phase (``phase_modes=1``) and marginalised over
their phase modes (the default), and for every flat how much of one circumference its
impacts leave unseen ("blind": every bay's modelled reading within one noise standard
deviation of a round wheel's).

    python benchmarks/identify_diagnose.py --seed 31 --wagons 9 10 11 12 --passages DIR

The wagons are drawn as the study draws them (``--seed``, ``--sites``, ``--site-seed``), so
``--passages`` may share the study's folder. Writes ``--out`` (JSON) and prints a table.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _study():
    import importlib.util

    spec = importlib.util.spec_from_file_location("identify_study",
                                                  ROOT / "benchmarks" / "identify_study.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def blind_fraction(table, bays, kind: str, factor: float, length: float,
                   sigma: float = float(np.hypot(0.03, 0.02))) -> float:
    """The fraction of one circumference's impact phases at which a flat of ``kind``, l / l0
    ``factor`` (the table's nearest shape) and ``length`` [m] reads, in every bay, within
    ``sigma`` (relative) of a round wheel (both averaged over the table's realisations)."""
    from wfjax.identify import prediction
    from wfjax.identify.inference import PHASE_REFINE

    s = min(range(len(table.shapes)), key=lambda i: (table.shapes[i][0] != kind) * 10 + abs(
        (table.shapes[i][1] or 1.0) - factor))
    mu = prediction.predict_refined(table, bays, [length, 0.0], PHASE_REFINE)[s].mean(axis=2)
    flat, round_ = mu[0], mu[1]  # [P, n_bays]
    return float(np.mean(np.all(np.abs(flat - round_) <= sigma * round_, axis=-1)))


def diagnose(study, k: int, flats, site: int, args) -> list[dict]:
    """Every wheel of wagon ``k``: truth, passes, and both identifications."""
    from wfjax.identify import identify

    passages, truths = study.simulate_wagon(k, flats, site, args)
    out = [dict(t, wagon=k, site=site) | study.passes(i, passages, truths)
           for i, t in enumerate(truths[0])]
    for modes in (1, 4):
        t0 = time.perf_counter()
        res = identify(passages, phase_modes=modes)
        for row, w in zip(out, res.wheels, strict=True):
            lo, hi = w.post.interval("length", 0.9)
            row[f"modes{modes}"] = {
                "flagged": w.flagged, "p_flag": w.p_flag, "p_new": w.post.p_kind("new"),
                "median": float(w.post.length_quantiles([0.5])[0]), "int90": [lo, hi],
                "ppc_p": w.post.ppc_p, "s": time.perf_counter() - t0}
    tables = {round(t.speed, 9): t for t in res.tables}
    for row in out:
        if row["kind"] != "none":
            row["blind"] = [blind_fraction(tables[round(p.speed, 9)], p.detector_bays(),
                                           row["kind"], row["factor"], row["length"])
                            for p in passages]
    return out


def line(r: dict) -> str:
    def ans(a):
        return (f"{'FLAG' if a['flagged'] else 'ok  '} p={a['p_flag']:.2f} "
                f"{a['median'] * 1e3:4.0f} [{a['int90'][0] * 1e3:3.0f},{a['int90'][1] * 1e3:4.0f}]")

    gates = "".join("g" if g else "-" for g in r["in_gate"])
    blind = " blind " + "/".join(f"{b:.2f}" for b in r["blind"]) if "blind" in r else ""
    return (f"w{r['wagon']:>3} {r['wheel']} {r['kind']:>7} {r['length'] * 1e3:4.0f} mm "
            f"impacts {gates} max {'/'.join(f'{m / 1e3:.0f}' for m in r['max_readings'])} kN "
            f"| mode: {ans(r['modes1'])} | mixture: {ans(r['modes4'])}{blind}")


def study_blindness(path: str, speeds_kmh=(60.0, 100.0, 140.0)) -> dict:
    """Every flat of a study's results (``path``, JSON) with its blind fraction at each
    passage's speed (the response tables from the cache; no simulation): the missed flats
    >= 30 mm, and the expected number of flats >= 30 mm whose every passage falls where the
    detector reads them as round (the sum over flats of the product of their blind
    fractions: impacts drawn uniformly over the circumference, independently per passage)."""
    from wfjax.identify import forward as fwd

    rows = json.loads(Path(path).read_text())["wheels"]
    bays = np.arange(-1, 4)
    tables = [fwd.build_table(v / 3.6) for v in speeds_kmh]
    long = [r for r in rows if r["kind"] != "none" and r["length"] >= 0.03]
    for r in long:
        factor = r["length"] / np.sqrt(8 * tables[0].wheel_radius * r["depth"])  # l / l0
        r["blind"] = [blind_fraction(t, bays, r["kind"], factor, r["length"]) for t in tables]
    missed = [r for r in long if not r["flagged"]]
    for r in missed:
        lo, hi = r["length_0.9"]
        print(f"missed: wagon {r['wagon']} {r['kind']} {r['length'] * 1e3:.0f} mm, impacts "
              f"{''.join('g' if g else '-' for g in r.get('in_gate', []))}, max readings "
              f"{'/'.join(f'{m / 1e3:.0f}' for m in r.get('max_readings', []))} kN, P(l >= "
              f"20 mm) {r['p_flag']:.2f}, median {r['length_median'] * 1e3:.0f} mm, 90 % "
              f"[{lo * 1e3:.0f}, {hi * 1e3:.0f}] mm "
              f"({'covers' if lo <= r['length'] <= hi else 'misses'} the truth), blind "
              f"{'/'.join(f'{b:.2f}' for b in r['blind'])}")
    expected = float(sum(np.prod(r["blind"]) for r in long))
    print(f"flats >= 30 mm: {len(long)}, missed {len(missed)}; expected all-blind: "
          f"{expected:.2f}; median blind fraction per passage "
          f"{np.median([b for r in long for b in r['blind']]):.2f}")
    return {"n_long": len(long), "missed": missed, "expected_all_blind": expected,
            "blind": [{"kind": r["kind"], "length": r["length"], "blind": r["blind"]}
                      for r in long]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=31)
    ap.add_argument("--site-seed", type=int, default=31)
    ap.add_argument("--sites", type=int, default=4)
    ap.add_argument("--speeds-kmh", default="60,100,140")
    ap.add_argument("--wagons", type=int, nargs="+", default=[])
    ap.add_argument("--study", metavar="JSON", help="instead: the blind fractions of a "
                    "study's flats (identify_study.py's results) and its missed flats")
    ap.add_argument("--passages", metavar="DIR")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" /
                                         "identify_diagnose.json"))
    args = ap.parse_args(argv)
    from wfjax.cli import enable_compilation_cache

    enable_compilation_cache()
    if args.study:
        out = Path(args.out)
        old = json.loads(out.read_text()) if out.exists() else {}
        old["study_blindness"] = study_blindness(args.study)
        out.write_text(json.dumps(old, indent=1, default=float) + "\n")
        return 0
    study = _study()
    rng = np.random.default_rng(args.seed)
    rows = []
    for k in range(max(args.wagons) + 1):
        flats, site = study.draw_wagon(rng, args.sites)
        if k in args.wagons:
            rows += diagnose(study, k, flats, site, args)
            for r in rows[-4:]:
                print(line(r), flush=True)
    out = Path(args.out)
    old = json.loads(out.read_text()) if out.exists() else {}
    old[f"seed{args.seed}"] = {"args": vars(args), "wheels": rows}
    out.write_text(json.dumps(old, indent=1, default=float) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

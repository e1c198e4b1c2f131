"""The 20-wagon train benchmark of ``wfjax identify`` (issue 31, item 5: "a 20-wagon train in
under 20 minutes, batched, not looped").

The train: ``--wagons`` (default 20) four-axle wagons of the study's layout (wheels at 0, 2.5,
17.5, 20 m; ``benchmarks/identify_study.py``), one every ``--pitch-m`` (default 25 m: 5 m
between one wagon's last wheel and the next one's first), 80 wheels in one passage and one
readings CSV (``wfjax.identify.passages_csv`` / ``read_passages``). Flats (``--flats``,
``wheel:kind:length_mm[:l/l0]``; default six, 30-90 mm, three new and three rounded, on
six different bogies), every other wheel round. One passage at ``--speed-kmh`` (default 100)
over one detector site: a 5-bay detector (3.25 m, longer than the 2.83 m circumference, modes
to 20 kHz), the site's support scatter (cv 0.1) and ISO 3095 limit rail roughness drawn from
``--site-seed``, independently of the identification's own realisations; 3 % relative
Gaussian noise; Hertz-trajectory contact in the truth and in the identification.

Batched, how: eighty wheels do not fit on one modelled track, so the train is a batch of
bogies (wheels closer than 4 m, ``wfjax.identify.pipeline.GROUP_GAP``), each coupled within
itself on its own track window. The truth is
``wfjax.identify.synthetic.simulate_passage(..., site_seed=...)``: one compiled program for
the bogie layout and ``vmap``-ed batches over the 40 bogies
(``wfjax.identify.forward.coupled_batch``: the bogies' flats enter as their wheels' contact
laws and flat delays, one batch per combination of flat kinds). The identification is
``wfjax.identify.identify`` with its defaults: the response table (one single-wheel table
per speed, batched over lengths x impact positions x roughness realisations) is built once
for the whole train; every wheel's grid posterior is then numpy (a Python loop over the 80
wheels, about 0.1 s each); the neighbour correction runs every bogie with a probable flat
coupled, and its wheels alone, as one batch each (``coupled_batch``), not a loop over
bogies.

Timed: the truth; ``identify`` end to end (table, compilation, posteriors, neighbour
corrections, flags, decisions and uncertainty) in a fresh process with an empty
``WFJAX_CACHE_DIR`` (cold: the response table, the track's modal model and every XLA
compilation built there), then in another fresh process on the cache that run left (warm).

    python benchmarks/identify_train.py                 # the docs/identify.md run
    python benchmarks/identify_train.py --no-cold       # warm only (builds the table once)
    python benchmarks/identify_train.py --wagons 2 --table-options \\
        '{"n_offsets": 2, "n_roughness": 1}' --flats 1:new:60 --out /tmp/t.json   # a smoke test

Writes ``benchmarks/results/identify_train.json`` (``--out``) and prints a Markdown summary.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
WAGON = (0.0, 2.5, 17.5, 20.0)
DEFAULT_FLATS = "1:new:30,14:rounded:45:1.8,27:new:60,42:rounded:75:1.7,55:new:90,70:rounded:60:1.9"


def layout(wagons: int, pitch: float) -> np.ndarray:
    """[4 wagons] wheel positions [m] behind the leading wheel."""
    return np.concatenate([k * pitch + np.asarray(WAGON) for k in range(wagons)])


def simulate(args, csv_path: Path) -> tuple[list, dict]:
    """The passage (written to ``csv_path``) and its truth; (truth rows, timings [s])."""
    from wfjax.identify import passages_csv
    from wfjax.identify.synthetic import parse_flats, simulate_passage
    from wfjax.scenario.sensors import Detector

    positions = layout(args.wagons, args.pitch_m)
    flats = parse_flats(args.flats)
    t0 = time.perf_counter()
    passage, truth = simulate_passage(positions, flats, args.speed_kmh / 3.6, Detector(5, -1),
                                      noise=0.03, seed=args.seed, site_seed=args.site_seed)
    t1 = time.perf_counter()
    csv_path.write_text(passages_csv([passage]))
    return truth, {"truth_s": t1 - t0}


def identify_child(csv_path: str, table_options: str, result_path: str) -> int:
    """In its own process: read the passage CSV, identify it, write the rows and the time."""
    t_start = time.perf_counter()
    from wfjax.cli import enable_compilation_cache

    enable_compilation_cache()
    from wfjax.identify import identify, read_passages

    passages = read_passages(csv_path)
    stages: dict = {}

    def progress(stage, done, total):  # every stage's last report [s from the call's start]
        if stage not in stages:
            print(f"  {stage} ...", file=sys.stderr, flush=True)
        stages[stage] = time.perf_counter()

    t0 = time.perf_counter()
    res = identify(passages, table_options=json.loads(table_options) or None, progress=progress)
    t1 = time.perf_counter()
    rows = []
    for w in res.wheels:
        lo, hi = w.post.interval("length", 0.9)
        rows.append({"wheel": w.wheel, "flagged": bool(w.flagged), "p_flag": w.p_flag,
                     "p_new": w.post.p_kind("new"),
                     "length_median": float(w.post.length_quantiles([0.5])[0]),
                     "length_90": [lo, hi], "misfit": bool(w.misfit), "ppc_p": w.post.ppc_p,
                     "max_reading": w.max_reading, "p_peak_exceeds": w.p_exceed,
                     "decisions": w.decisions})
    Path(result_path).write_text(json.dumps({
        "identify_s": t1 - t0, "process_s": time.perf_counter() - t_start,
        "stages_s": {k: v - t0 for k, v in stages.items()}, "rows": rows}, default=float))
    return 0


def run_identify(csv_path: Path, cache_dir: Path, args, label: str) -> dict:
    """``identify`` of the passage in a fresh process with ``WFJAX_CACHE_DIR=cache_dir``."""
    out = csv_path.with_name(f"identify_{label}.json")
    # on a GPU the parent (the truth) holds its memory: the child takes what it needs, not 75 %
    env = dict(os.environ, WFJAX_CACHE_DIR=str(cache_dir), XLA_PYTHON_CLIENT_PREALLOCATE="false")
    t0 = time.perf_counter()
    subprocess.run([sys.executable, __file__, "--child", str(csv_path), "--table-options",
                    args.table_options, "--child-out", str(out)], env=env, check=True)
    res = json.loads(out.read_text())
    res["wall_s"] = time.perf_counter() - t0
    print(f"  identify ({label}): {res['identify_s']:.1f} s in the call, "
          f"{res['wall_s']:.1f} s the process", file=sys.stderr, flush=True)
    return res


def machine() -> str:
    """The CPU, and the JAX accelerator where there is one."""
    import jax

    cpu = f"{os.cpu_count()}-core CPU ({platform.processor() or platform.machine()})"
    if jax.default_backend() == "cpu":
        return cpu + ", shared"
    return f"{jax.devices()[0].device_kind} ({jax.default_backend()}), {cpu}"


def score(truth: list, rows: list) -> dict:
    """Flagged / missed / false against the truth."""
    flats = [t for t in truth if t["kind"] != "none"]
    rounds = [t for t in truth if t["kind"] == "none"]
    flag = {r["wheel"]: r["flagged"] for r in rows}
    return {"n_flats": len(flats), "n_round": len(rounds),
            "flats_flagged": sum(flag[t["wheel"]] for t in flats),
            "flats_missed": [t["wheel"] for t in flats if not flag[t["wheel"]]],
            "flats_30mm_or_longer_missed": [t["wheel"] for t in flats
                                            if t["length"] >= 0.03 and not flag[t["wheel"]]],
            "round_flagged": [t["wheel"] for t in rounds if flag[t["wheel"]]],
            "misfit": [r["wheel"] for r in rows if r["misfit"]]}


def markdown(result: dict) -> str:
    """The summary: times, then every flat wheel and every flagged wheel against its truth."""
    m, s, t = result["meta"], result["score"], result["times"]
    lines = [f"## Identify: {m['wagons']}-wagon train ({m['n_wheels']} wheels, "
             f"{m['speed_kmh']:g} km/h, {m['date']})", "",
             f"- truth (40 bogies batched, coupled within each bogie): {t['truth_s']:.1f} s",
             f"- identification, warm cache (fresh process): {t['identify_warm_s']:.1f} s in "
             f"`identify`, {t['identify_warm_process_s']:.1f} s the process"]
    if t.get("identify_cold_s") is not None:
        lines.append(f"- identification, cold (empty WFJAX_CACHE_DIR, fresh process): "
                     f"{t['identify_cold_s']:.1f} s in `identify` "
                     f"({t['identify_cold_s'] / 60:.1f} min), {t['identify_cold_process_s']:.1f}"
                     " s the process")
    lines += [f"- flats flagged: {s['flats_flagged']} of {s['n_flats']} (missed: wheels "
              f"{s['flats_missed'] or 'none'}); round wheels flagged: {len(s['round_flagged'])} "
              f"of {s['n_round']} ({s['round_flagged'] or 'none'}); misfit: "
              f"{s['misfit'] or 'none'}", "",
              "| wheel | truth | length mm | impact m | flagged | P(l >= 20 mm) | P(new) | "
              "length median [90 %] mm |", "|---|---|---|---|---|---|---|---|"]
    for tr, r in zip(result["truth"], result["rows"], strict=True):
        if tr["kind"] == "none" and not r["flagged"]:
            continue
        lo, hi = (1e3 * x for x in r["length_90"])
        lines.append(f"| {tr['wheel']} | {tr['kind']} | {1e3 * tr['length']:.0f} | "
                     f"{tr['impact']:.2f} | {'yes' if r['flagged'] else 'no'} | "
                     f"{r['p_flag']:.2f} | {r['p_new']:.2f} | {1e3 * r['length_median']:.0f} "
                     f"[{lo:.0f}, {hi:.0f}] |")
    lines.append("")
    lines.append(f"Every other wheel: round, not flagged. Machine: {m['machine']}.")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--wagons", type=int, default=20)
    ap.add_argument("--pitch-m", type=float, default=25.0, help="wagon length [m]")
    ap.add_argument("--speed-kmh", type=float, default=100.0)
    ap.add_argument("--flats", default=DEFAULT_FLATS, help="wheel:kind:length_mm[:l/l0], ...")
    ap.add_argument("--seed", type=int, default=20, help="impacts and noise")
    ap.add_argument("--site-seed", type=int, default=20, help="the site's supports and rail")
    ap.add_argument("--table-options", default="{}", help="JSON: build_table options (smoke)")
    ap.add_argument("--no-cold", action="store_true", help="skip the empty-cache run")
    ap.add_argument("--warm-cache", default=None,
                    help="WFJAX_CACHE_DIR of the warm run without a cold one (default: the "
                    "user's)")
    ap.add_argument("--work-dir", default=None, help="passage CSV and the runs' outputs")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" /
                                         "identify_train.json"))
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--child-out", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        return identify_child(args.child, args.table_options, args.child_out)

    from wfjax._cache import cache_directory
    from wfjax.cli import enable_compilation_cache

    enable_compilation_cache()
    work = Path(args.work_dir or tempfile.mkdtemp(prefix="identify_train_"))
    work.mkdir(parents=True, exist_ok=True)
    csv_path = work / "passage.csv"
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    truth, times = simulate(args, csv_path)
    print(f"  truth: {times['truth_s']:.1f} s ({len(truth)} wheels)", file=sys.stderr,
          flush=True)
    if args.no_cold:
        cache = Path(args.warm_cache) if args.warm_cache else cache_directory()
        warm = run_identify(csv_path, cache, args, "warm")
        cold = None
    else:
        cache = work / "cache"
        if cache.exists() and any(cache.iterdir()):
            raise SystemExit(f"{cache}: not empty; the cold run needs an empty cache")
        cache.mkdir(exist_ok=True)
        cold = run_identify(csv_path, cache, args, "cold")
        warm = run_identify(csv_path, cache, args, "warm")
    if cold is not None:  # the same answer from a cold and a warm cache
        same = all(a["flagged"] == b["flagged"] and abs(a["p_flag"] - b["p_flag"]) < 1e-9
                   for a, b in zip(cold["rows"], warm["rows"], strict=True))
    else:
        same = None
    times |= {"identify_warm_s": warm["identify_s"], "identify_warm_process_s": warm["wall_s"],
              "identify_warm_stage_ends_s": warm["stages_s"],
              "identify_cold_s": cold and cold["identify_s"],
              "identify_cold_process_s": cold and cold["wall_s"],
              "identify_cold_stage_ends_s": cold and cold["stages_s"],
              "total_s": time.perf_counter() - t0}
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                            capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "wfjax"], cwd=ROOT,
                           capture_output=True, text=True).stdout.split("\n")
    dirty = [line.strip() for line in dirty if line.strip()]
    meta = {"command": "python benchmarks/identify_train.py " + " ".join(
                a for a in (argv if argv is not None else sys.argv[1:])),
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "machine": machine(),
            "load_average_start": load0, "load_average_end": os.getloadavg(),
            "commit": commit, "wfjax_uncommitted": dirty, "wagons": args.wagons,
            "n_wheels": len(truth), "pitch_m": args.pitch_m, "speed_kmh": args.speed_kmh,
            "flats": args.flats, "seed": args.seed, "site_seed": args.site_seed,
            "table_options": json.loads(args.table_options), "detector_bays": 5,
            "noise": 0.03, "contact": "hertz-trajectory",
            "cold_and_warm_answers_equal": same}
    result = {"meta": meta, "times": times, "score": score(truth, warm["rows"]),
              "truth": truth, "rows": warm["rows"],
              "passage_csv": csv_path.read_text()}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1, default=float) + "\n")
    print(markdown(result), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

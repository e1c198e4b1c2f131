"""Validation study of ``wfjax identify`` (issue 31, item 4): held-out synthetic passages
from a richer model than the identification's, identified, scored.

Truth (:func:`wfjax.identify.synthetic.simulate_passage`): a four-axle wagon (wheels at 0,
2.5, 17.5, 20 m) with one or two flats of random length U(20, 100) mm, new or rounded
(l / l0 ~ U(1.6, 2.0)); every wagon passes one detector site once at each of
``--speeds-kmh`` (default 60, 100, 140 km/h), its flats striking at a new continuous random
point of one circumference each time; each bogie coupled on its own track window; the site
(``--sites`` of them, one drawn per wagon) is a support scatter (lognormal pad and ballast
stiffness, cv 0.1) and a rail roughness realisation (ISO 3095 limit), drawn independently
of the identification's nuisance realisations; 3 % relative Gaussian noise; a 5-bay
detector (3.25 m, more than a wheel circumference of 2.83 m) with modes to 20 kHz.
Identification: :func:`wfjax.identify.identify` with its defaults (Hertz-trajectory;
``--identify-contact 3d``: response tables with every flat's exact 3D table), the wagon's
passages together.

    python benchmarks/identify_study.py --flats 100 --docs     # the docs/identify.md run
    python benchmarks/identify_study.py --flats 3              # a smoke test

Writes ``benchmarks/results/identify_study.json``; ``--docs`` also writes the summary and
calibration table between the markers of ``docs/identify.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import beta, binom

ROOT = Path(__file__).resolve().parents[1]
WAGON = (0.0, 2.5, 17.5, 20.0)
LEVELS = (0.5, 0.8, 0.9)


def draw_flats(rng) -> list:
    """One or two flats on random wheels of the wagon."""
    from wfjax.identify.synthetic import TrainFlat

    wheels = rng.choice(4, size=int(rng.integers(1, 3)), replace=False)
    out = []
    for w in sorted(int(x) for x in wheels):
        kind = "new" if rng.random() < 0.5 else "rounded"
        out.append(TrainFlat(w, kind, float(rng.uniform(0.02, 0.10)),
                             float(rng.uniform(1.6, 2.0))))
    return out


def draw_wagon(rng, sites: int) -> tuple[list, int]:
    """(flats, site) of the next wagon from ``rng``: its flats (:func:`draw_flats`) and which
    of ``sites`` detector sites it passes. Every script that replays the study's wagons
    draws them with this, in this order."""
    return draw_flats(rng), int(rng.integers(sites))


def score_wheel(truth: dict, res) -> dict:
    """The wheel's truth and what the identification said about it."""
    post = res.post
    row = {"kind": truth["kind"], "length": truth["length"], "depth": truth["depth"],
           "impact": truth["impact"], "flagged": res.flagged, "p_flag": res.p_flag,
           "p_new": post.p_kind("new"), "misfit": res.misfit, "ppc_p": post.ppc_p,
           "length_median": float(post.length_quantiles([0.5])[0]),
           "depth_median": float(post.depth_quantiles([0.5])[0])}
    for level in LEVELS:
        row[f"length_{level}"] = post.interval("length", level)
        row[f"depth_{level}"] = post.interval("depth", level)
    return row


def clopper_pearson(k: int, n: int, conf: float = 0.95) -> tuple[float, float]:
    """Two-sided ``conf`` Clopper-Pearson interval of a binomial proportion k / n."""
    a = (1 - conf) / 2
    lo = 0.0 if k == 0 else float(beta.ppf(a, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - a, k + 1, n - k))
    return lo, hi


def median_interval(values, conf: float = 0.95) -> tuple[float, float]:
    """Distribution-free ``conf`` interval of the median of the population ``values`` [n]
    were drawn from: the order statistics x_(j), x_(n+1-j), j the binomial(n, 1/2) quantile,
    covering at least ``conf`` whatever the distribution."""
    x = np.sort(np.asarray(values, float))
    j = int(binom.ppf((1 - conf) / 2, x.size, 0.5))  # P(B <= j - 1) < (1 - conf) / 2
    if j < 1:
        return float("-inf"), float("inf")
    return float(x[j - 1]), float(x[x.size - j])


def summarise(rows: list[dict]) -> dict:
    """Flags, errors, widths and the calibration table."""
    flats = [r for r in rows if r["kind"] != "none"]
    rounds = [r for r in rows if r["kind"] == "none"]
    err = [_error(r, "length") for r in flats]
    out = {"n_flats": len(flats), "n_round": len(rounds),
           "flagged_30mm_or_longer": [sum(r["flagged"] for r in flats if r["length"] >= 0.03),
                                      sum(1 for r in flats if r["length"] >= 0.03)],
           "round_flagged": [sum(r["flagged"] for r in rounds), len(rounds)],
           "median_abs_rel_error_length": float(np.median(err)) if err else None,
           "median_abs_rel_error_length_ci95": list(median_interval(err)) if err else None,
           "misfit_passages": sum(r["misfit"] for r in rows),
           "kind_correct": [sum((r["p_new"] >= 0.5) == (r["kind"] == "new") for r in flats),
                            len(flats)]}
    long = [r for r in flats if r["length"] >= 0.04]
    out["median_width90_over_length_40mm_plus"] = float(np.median(
        [(r["length_0.9"][1] - r["length_0.9"][0]) / r["length"] for r in long])) \
        if long else None
    table = []
    for what in ("length", "depth"):
        for level in LEVELS:
            k = sum(r[f"{what}_{level}"][0] <= r[what] <= r[f"{what}_{level}"][1]
                    for r in flats)
            lo, hi = clopper_pearson(k, len(flats))
            table.append({"quantity": what, "nominal": level, "covered": k, "n": len(flats),
                          "observed": k / max(len(flats), 1), "cp95": [lo, hi],
                          "calibrated": lo <= level <= hi})
    out["calibration"] = table
    out["by_length"] = {
        name: {"n": len(sub), "length_error": _median([_error(r, "length") for r in sub]),
               "depth_error": _median([_error(r, "depth") for r in sub])}
        for name, sub in (("under_40mm", [r for r in flats if r["length"] < 0.04]),
                          ("40mm_plus", [r for r in flats if r["length"] >= 0.04]))}
    out["by_kind"] = {}
    for kind in ("new", "rounded"):
        sub = [r for r in flats if r["kind"] == kind]
        lg = [r for r in sub if r["length"] >= 0.04]
        out["by_kind"][kind] = {
            "n": len(sub),
            "error": _median([_error(r, "length") for r in sub]),
            "width": _median([(r["length_0.9"][1] - r["length_0.9"][0]) / r["length"]
                              for r in lg])}
    return out


def _error(row: dict, what: str) -> float:
    """A flat's absolute relative error of its ``what`` ("length", "depth") median."""
    return abs(row[f"{what}_median"] - row[what]) / row[what]


def _by_length_line(by: dict) -> str:
    """The markdown line of the errors by true length (:func:`summarise`'s ``by_length``)."""
    a, b = by["under_40mm"], by["40mm_plus"]
    return (f"- median absolute error, flats under 40 mm ({a['n']}): length "
            f"{100 * a['length_error']:.1f} %, depth {100 * a['depth_error']:.1f} %; "
            f"40 mm or longer ({b['n']}): length {100 * b['length_error']:.1f} %, depth "
            f"{100 * b['depth_error']:.1f} %")


def _median(values) -> float:
    return float(np.median(values)) if len(values) else float("nan")


def run_line(meta: dict) -> str:
    """One run's command, size and times."""
    return (f"`python benchmarks/identify_study.py --flats {meta['flats']} --speeds-kmh "
            f"{meta['speeds_kmh']} --sites {meta['sites']} --seed {meta['seed']}"
            f"{_truth_option(meta)}` "
            f"({meta['date']}): {meta['wagons']} wagons, {meta['wall_s'] / 60:.1f} min on the "
            f"shared 2-core CPU ({_truth_time(meta)}, identification "
            f"{meta['identify_s'] / 60:.1f} min, median "
            f"{meta['identify_median_s_per_wagon']:.0f} s per wagon of "
            f"{len(str(meta['speeds_kmh']).split(','))} passages)")


def _truth_time(meta: dict) -> str:
    if meta.get("passages") and meta["simulate_s"] < 60:
        return "truth read from `--passages`, simulated beforehand by `--simulate-only`"
    return f"truth {meta['simulate_s'] / 60:.1f} min"


def _truth_option(meta: dict) -> str:
    out = ""
    for key in ("truth_contact", "identify_contact"):
        law = meta.get(key, "hertz-trajectory")
        out += "" if law == "hertz-trajectory" else f" --{key.replace('_', '-')} {law}"
    out += f" --skip-wagons {meta['skip_wagons']}" if meta.get("skip_wagons") else ""
    return out + (f" --wagons {meta['wagons_chosen']}" if meta.get("wagons_chosen") else "")


def markdown(summary: dict, metas: list[dict]) -> str:
    """The study's section of docs/identify.md (``metas``: every run merged into it)."""
    s = summary
    by = s["by_kind"]
    lines = [("Runs, merged: " if len(metas) > 1 else "Run: ") +
             "; ".join(run_line(m) for m in metas) +
             f". In all {s['n_flats']} flats, {s['n_round']} round wheels.", "",
             f"- flats >= 30 mm flagged: {s['flagged_30mm_or_longer'][0]} of "
             f"{s['flagged_30mm_or_longer'][1]}; round wheels flagged: "
             f"{s['round_flagged'][0]} of {s['round_flagged'][1]}",
             f"- median absolute error of the length median: "
             f"{100 * (s['median_abs_rel_error_length'] or float('nan')):.1f} % (new "
             f"{100 * by['new']['error']:.1f} %, rounded {100 * by['rounded']['error']:.1f} %;"
             f" 95 % interval of the median, distribution-free: {_ci_text(s)})",
             _by_length_line(s["by_length"]),
             f"- median 90 % interval width / length, flats >= 40 mm: "
             f"{100 * (s['median_width90_over_length_40mm_plus'] or float('nan')):.0f} % (new "
             f"{100 * by['new']['width']:.0f} %, rounded {100 * by['rounded']['width']:.0f} %)",
             f"- kind (new/rounded) right at P >= 0.5: {s['kind_correct'][0]} of "
             f"{s['kind_correct'][1]}; wheels reported as misfit: {s['misfit_passages']}",
             "", "| quantity | nominal | observed coverage | covered / n | 95 % "
             "Clopper-Pearson | nominal inside |", "|---|---|---|---|---|---|"]
    for t in s["calibration"]:
        lines.append(f"| {t['quantity']} | {t['nominal']:.2f} | {t['observed']:.3f} | "
                     f"{t['covered']} / {t['n']} | [{t['cp95'][0]:.3f}, {t['cp95'][1]:.3f}] "
                     f"| {'yes' if t['calibrated'] else 'no'} |")
    return "\n".join(lines) + "\n"


def _ci_text(s: dict) -> str:
    ci = s.get("median_abs_rel_error_length_ci95")
    return "-" if not ci else f"[{100 * ci[0]:.1f}, {100 * ci[1]:.1f}] %"


def speeds(args) -> list[float]:
    """[km/h] the speed of each of a wagon's passages."""
    return [float(v) for v in str(args.speeds_kmh).split(",")]


def run_wagon(k: int, rng, args) -> tuple[list, dict]:
    """Wagon ``k``: its flats, one passage at each of ``args.speeds_kmh`` over one of
    ``args.sites`` detector sites, identified together; (per-wheel rows, timings [s])."""
    from wfjax.identify import identify
    from wfjax.identify.pipeline import PHASE_ERROR, PHASE_MODES

    flats, site = draw_wagon(rng, args.sites)
    t0 = time.perf_counter()
    passages, truths = simulate_wagon(k, flats, site, args)
    t1 = time.perf_counter()
    if getattr(args, "simulate_only", False):
        rows = [t | {"wagon": k, "site": site, "flagged": False} for t in truths[0]]
        return rows, {"simulate_s": t1 - t0, "identify_s": 0.0}
    res = identify(passages, coupling_iterations=args.coupling,
                   contact=getattr(args, "identify_contact", "hertz-trajectory"),
                   phase_modes=getattr(args, "phase_modes", PHASE_MODES),
                   phase_error=getattr(args, "phase_error_m", PHASE_ERROR))
    t2 = time.perf_counter()
    rows = [score_wheel(t, w) | {"wagon": k, "site": site} | passes(i, passages, truths)
            for i, (t, w) in enumerate(zip(truths[0], res.wheels, strict=True))]
    return rows, {"simulate_s": t1 - t0, "identify_s": t2 - t1}


def simulate_wagon(k: int, flats, site: int, args) -> tuple[list, list]:
    """(passages, per passage the wheels' truth) of wagon ``k`` (kept in and reused from the
    ``--passages`` folder; a kept first passage's truth only: the others' impacts redrawn by
    :func:`wfjax.identify.synthetic.truth_of`, their peak forces unknown)."""
    from wfjax.identify.synthetic import simulate_passage, truth_of
    from wfjax.scenario.sensors import Detector

    seeds = [args.seed * 100003 + 101 * k + j + 1 for j in range(len(speeds(args)))]
    cached = _cached_passages(args, k)
    if cached is not None:
        passages, truths = cached
        if isinstance(truths[0], dict):  # the first passage's truth only
            truths = [truths] + [truth_of(len(WAGON), flats, s) for s in seeds[1:]]
        return passages, truths
    passages, truths = [], []
    for s, speed_kmh in zip(seeds, speeds(args), strict=True):
        p, tr = simulate_passage(WAGON, flats, speed_kmh / 3.6, Detector(5, -1),
                                 noise=0.03, seed=s, site_seed=args.site_seed * 1009 + site,
                                 contact=getattr(args, "truth_contact", "hertz-trajectory"))
        passages.append(p)
        truths.append(tr)
    _store_passages(args, k, passages, truths)
    return passages, truths


def passes(i: int, passages, truths) -> dict:
    """Wheel ``i`` in each passage: its flat's impact coordinate [m], whether it lies inside a
    gauge's gate (between the bay's bridges), the wheel's true peak contact force [N] (NaN
    where not kept) and its highest reading [N]."""
    from wfjax.identify import forward as fwd

    det = passages[0].detector()
    a, b = det.gauges(float(fwd.TRACK.sleeper_spacing))
    x = [float(t[i]["impact"]) for t in truths]
    return {"impacts": x, "in_gate": [bool(np.any((a <= v) & (v <= b))) for v in x],
            "peak_forces": [float(t[i].get("peak_force", float("nan"))) for t in truths],
            "max_readings": [float(np.max(p.readings[i])) for p in passages]}


def _passage_file(args, k: int):
    """The ``--passages`` cache file of wagon ``k`` (None without ``--passages``): named by
    everything that draws it (seeds, sites, speeds), not by the code's version: clear the
    folder when the model changes."""
    folder = getattr(args, "passages", None)
    if not folder:
        return None
    tag = f"s{args.seed}-ss{args.site_seed}-n{args.sites}-v{args.speeds_kmh.replace(',', '_')}"
    truth = getattr(args, "truth_contact", "hertz-trajectory")
    tag += "" if truth == "hertz-trajectory" else f"-{truth}"
    return Path(folder) / f"wagon-{tag}-{k}.pkl"


def _cached_passages(args, k: int):
    """(passages, truth) of wagon ``k`` from the ``--passages`` folder, or None."""
    import pickle

    path = _passage_file(args, k)
    if path is None or not path.exists():
        return None
    return pickle.loads(path.read_bytes())


def kept_passages(folder, k: int, seed: int = 41, site_seed: int = 31, sites: int = 4,
                  speeds_kmh: str = "60,100,140") -> tuple[list, list]:
    """(passages, per passage the wheels' truth) of wagon ``k`` (from 0) of a Hertz study
    kept in ``folder`` by ``--passages`` (the study's seeds and sites; default: the docs'
    seed 41 study). FileNotFoundError where that wagon was not kept."""
    args = argparse.Namespace(passages=str(folder), seed=seed, site_seed=site_seed,
                              sites=sites, speeds_kmh=speeds_kmh)
    kept = _cached_passages(args, k)
    if kept is None:
        raise FileNotFoundError(f"wagon {k} not kept in {folder}: {_passage_file(args, k)}")
    return kept


def _store_passages(args, k: int, passages, truth) -> None:
    import pickle

    path = _passage_file(args, k)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_bytes(pickle.dumps((passages, truth)))
        tmp.replace(path)


def run(args, checkpoint=None) -> tuple[list, dict]:
    """Simulate and identify wagons until ``args.flats`` flats are scored (or
    ``args.max_wagons``); (per-wheel rows, timings). ``checkpoint(rows, timings, wagons)`` is
    called after every 5 wagons."""
    rng = np.random.default_rng(args.seed)
    rows, t0 = [], time.perf_counter()
    times = {"simulate_s": 0.0, "identify_s": 0.0, "identify_per_wagon_s": []}
    k, chosen = 0, _chosen(args)
    while k < getattr(args, "skip_wagons", 0):  # drawn as before, neither simulated nor scored
        draw_wagon(rng, args.sites)
        k += 1
    while sum(r["kind"] != "none" for r in rows) < args.flats and k < args.max_wagons:
        if chosen is not None and k not in chosen:
            if k > max(chosen):
                break
            draw_wagon(rng, args.sites)  # drawn as in the whole run, not simulated
            k += 1
            continue
        wrows, t = run_wagon(k, rng, args)
        rows += wrows
        times["simulate_s"] += t["simulate_s"]
        times["identify_s"] += t["identify_s"]
        times["identify_per_wagon_s"].append(t["identify_s"])
        times["wall_s"] = time.perf_counter() - t0
        if getattr(args, "simulate_only", False):
            print(f"  wagon {k + 1} simulated ({times['wall_s']:.0f} s)", file=sys.stderr,
                  flush=True)
            k += 1
            continue
        print(f"  wagon {k + 1}: " + ", ".join(
            f"{r['kind']} {r['length'] * 1e3:.0f}->{r['length_median'] * 1e3:.0f} mm"
            f"{'*' if r['flagged'] else ''}" for r in wrows),
            f"(identify {t['identify_s']:.0f} s, total {times['wall_s']:.0f} s)",
            file=sys.stderr, flush=True)
        k += 1
        if checkpoint and k % 5 == 0:
            checkpoint(rows, times, len({r["wagon"] for r in rows}))
    return rows, times


def _chosen(args) -> set[int] | None:
    """The wagons ``--wagons`` names (their rows' ``wagon`` numbers), or None: every one."""
    spec = getattr(args, "wagons_chosen", None)
    return None if not spec else {int(w) for w in str(spec).split(",")}


def write_docs(text: str, section: str = "study") -> None:
    """``text`` between ``<!-- section -->`` and ``<!-- /section -->`` of docs/identify.md."""
    path = ROOT / "docs" / "identify.md"
    page = path.read_text()
    start, end = f"<!-- {section} -->\n", f"<!-- /{section} -->\n"
    i, j = page.index(start) + len(start), page.index(end)
    path.write_text(page[:i] + text + page[j:])


def main(argv=None) -> int:
    from wfjax.identify.pipeline import PHASE_ERROR, PHASE_MODES

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flats", type=int, default=100, help="flats to score (default 100)")
    ap.add_argument("--max-wagons", type=int, default=1000)
    ap.add_argument("--skip-wagons", type=int, default=0, help="draw the first N wagons "
                    "but neither simulate nor score them (extend a run; --merge the two)")
    ap.add_argument("--speeds-kmh", default="60,100,140",
                    help="one passage per wagon at each of these speeds")
    ap.add_argument("--sites", type=int, default=4, help="detector sites (support scatter "
                    "and rail roughness realisations) the wagons are drawn over")
    ap.add_argument("--seed", type=int, default=31, help="the wagons' draws")
    ap.add_argument("--site-seed", type=int, default=31, help="the sites' draws")
    ap.add_argument("--coupling", type=int, default=1)
    ap.add_argument("--truth-contact", default="hertz-trajectory",
                    help="the truth's contact model (3d: each flat's exact 3D table)")
    ap.add_argument("--identify-contact", default="hertz-trajectory",
                    help="the identification's contact law (3d: response tables of every "
                    "flat's exact 3D table; identify(contact=...))")
    ap.add_argument("--phase-modes", type=int, default=PHASE_MODES,
                    help="a neighbour's configurations its correction is marginalised over "
                    "(1: its most probable phase)")
    ap.add_argument("--phase-error-m", type=float, default=PHASE_ERROR,
                    help="the blur of a neighbour's phase posterior [m] (identify(phase_error))")
    ap.add_argument("--wagons", dest="wagons_chosen", metavar="LIST",
                    help="only these wagons, comma-separated, numbered as the "
                    "results' 'wagon' field (from 0); the others are drawn and skipped, so "
                    "each gets the flats and site of the whole run (a subset's figures, e.g. "
                    "its time per wagon, can be rerun)")
    ap.add_argument("--docs", action="store_true")
    ap.add_argument("--docs-section", default="study", help="the docs/identify.md markers "
                    "--docs writes between (study3d: the 3D-law study's)")
    ap.add_argument("--passages", metavar="DIR", help="keep every wagon's simulated "
                    "passages and truth here and reuse them (the truth is most of the time)")
    ap.add_argument("--simulate-only", action="store_true",
                    help="simulate (and keep, with --passages) the passages; identify none")
    ap.add_argument("--merge", nargs="+", metavar="JSON",
                    help="merge these runs' results into --out (and the docs) instead; a "
                    "wagon in a later run replaces its rows of the earlier ones")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" /
                                         "identify_study.json"))
    args = ap.parse_args(argv)
    from wfjax.cli import enable_compilation_cache

    enable_compilation_cache()

    def save(rows, times, wagons):
        summary = summarise(rows)
        meta = {k: v for k, v in vars(args).items() if k not in ("docs", "out")}
        meta |= {"wagons": wagons, "date": time.strftime("%Y-%m-%d", time.gmtime())} | times
        meta["identify_median_s_per_wagon"] = float(np.median(times["identify_per_wagon_s"]))
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps({"meta": meta, "summary": summary,
                                              "wheels": rows}, indent=1, default=float) + "\n")
        text = markdown(summary, [meta])
        print(text, flush=True)
        if args.docs:
            write_docs(text, args.docs_section)

    if args.merge:
        return merge(args.merge, args.out, args.docs, args.docs_section)
    if args.simulate_only:
        rows, times = run(args)
        print(f"{len({r['wagon'] for r in rows})} wagons simulated in "
              f"{times['simulate_s'] / 60:.1f} min", flush=True)
        return 0
    rows, times = run(args, save)
    save(rows, times, len({r["wagon"] for r in rows}))
    return 0


def merge(paths: list[str], out: str, docs: bool, section: str = "study") -> int:
    """Merge the results of runs (``paths``, JSON) into ``out``; with ``docs`` into
    docs/identify.md too. A wagon in a later run replaces its rows of the earlier ones (a
    rerun of chosen wagons, ``--wagons``, after a change that touches only them)."""
    runs = [json.loads(Path(p).read_text()) for p in paths]
    metas, rows = [], []
    for d in runs:  # a merged run's meta is the list of its runs'
        first = len(metas)
        metas += d["meta"] if isinstance(d["meta"], list) else [d["meta"]]
        again = {r["wagon"] for r in d["wheels"]}
        rows = [r for r in rows if r["wagon"] not in again]
        rows += [r | {"run": first + r.get("run", 0)} for r in d["wheels"]]
    rows.sort(key=lambda r: r["wagon"])
    summary = summarise(rows)
    Path(out).write_text(json.dumps({"meta": metas, "summary": summary, "wheels": rows},
                                    indent=1, default=float) + "\n")
    text = markdown(summary, metas)
    print(text, flush=True)
    if docs:
        write_docs(text, section)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Issue 30's speed check: old (9bf324c, before the restructuring) against new (this tree).

Issue 30 asks that speed be no worse: the paired median ratio new/old at most 1.05 over at
least 5 interleaved rounds from empty caches, for the main job (cold and warm), the Fig. 8
set, the 3D fit and the gradient-to-forward ratio.

Method. The old code is a ``git worktree`` of ``--old-commit`` at ``--old`` (made with
``git worktree add --detach`` when missing), the new code is ``--new`` (default: this
repository's working tree). Every measurement is a fresh subprocess of the same Python (this
venv) with ``PYTHONPATH=<tree>`` and the working directory a temporary folder, so the tree's
``wfjax`` is imported, not the editable install (checked at the start for both trees:
``wfjax.__file__`` must lie in the tree; the Python snippets report it again). Each tree gets a
fresh, empty ``WFJAX_CACHE_DIR`` per round and measurement group (modal models, 3D tables and
families, and the ``wfjax`` command's persistent XLA compilation cache, ``<dir>/xla``), so the
cold runs build and compile everything. Each round runs every group in both trees, old first
in even rounds and new first in odd ones (round 1: old, new; round 2: new, old; ...), so the
two trees of a pair run minutes apart under the same machine load. Per measurement: each
round's ratio new/old, their median (the paired median ratio), and both trees' medians.

Groups and measurements (wall time of the subprocess unless said otherwise):

* ``main``: the README's main job, ``wfjax sweep`` (its install step left out), in an empty
  cache ("main job cold"), then again on the cache it left ("main job warm");
* ``fig8``: the Fig. 8 set, ``wfjax figures --only 8 --out DIR`` (docs/reproduction.md: 8
  rounded flats 0.25-2.00 mm, 29 speeds, 8 positions, 3D, R_R = 0.45 m; one parametric-family
  sweep), cold then warm as the main job;
* ``fit3d``: the 3D fit of notebooks/fit_flat_3d.ipynb in its fast mode (``WFJAX_FAST=1``:
  2.5 mm elements, coarse steps, 5 speeds 40-140 km/h, one impact position; truth from the
  exact per-flat 3D table with 3 % noise, start 50 % off; the notebook's gradient check left
  out): "3D fit" is the ``fit.fit_flat(..., contact="3d")`` call (family build, compilation,
  iterations), "3D fit script" the whole process (import, truth, fit);
* ``gradient``: the case of ``bench_gradient.py`` (3D parametric family, 2 mm elements, 10
  speeds 30-140 km/h, one position): after compiling, ``--grad-repeats`` rounds of the jitted
  forward (loss only) then the jitted ``jax.value_and_grad`` through the adjoint
  (``max_force_model(adjoint=True)``, as ``fit_flat``'s reverse mode), one unrecorded warm-up
  round first; "gradient / forward" is the median of the per-call-pair ratios (in x forward,
  not seconds); the forward and gradient medians [s] are reported too.

* ``rough`` (issue 33): 1,000 ISO 3095-limit rail roughness realisations as the batch axis
  of one ``sweep`` (rounded flat 0.9 mm x 100 mm, 100 km/h, impact at 0.1 m, the exact 3D
  table), as ``bench_roughness.py --contact 3d``: the first call (table build and compile)
  and the second, warm call inside the same process.

``--quick`` (smoke test, not for the record): Fig. 8 with ``--fast`` (2 depths, 3 speeds, 2
positions), the fit with 3 speeds, the gradient with 3 speeds and 3 repeats; the main job
unchanged.

Run: ``python benchmarks/bench_issue30.py [--rounds 5] [--only main,fig8,fit3d,gradient]
[--json benchmarks/results/bench_issue30.json]``. Progress to stderr (one line per run), a
Markdown table to stdout, everything (each run, load averages, CPU times, results) to the
JSON file.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
OLD_COMMIT = "9bf324c"
MARK = "BENCH_ISSUE30 "
GROUPS = ("main", "fig8", "fit3d", "gradient", "rough")
RATIO = "gradient / forward [x forward]"  # a ratio per tree, not seconds
SUMMARY_KEYS = ("flats", "peak_axle_acc_m_s2", "wall_time_s")  # of sweep.json / fig8.json

FIT3D = """
import dataclasses, json, time
t_start = time.perf_counter()
import numpy as np
import wfjax as wf
from wfjax import fit
track = wf.Track.comparison()
speeds = np.linspace(40.0, 140.0, {n_speeds}) / 3.6
positions = [0.1]
config = wf.SimConfig(contact_element=2.5e-3, max_travel_step=2e-3, max_time_step=5e-5)
truth = wf.Flat.rounded(depth=0.9e-3, length=0.100)
initial = wf.Flat.rounded(depth=1.35e-3, length=0.150)
param = fit.parametrisation_for(initial)
truth_b = dataclasses.replace(truth, extent_bound=param.extent_bound)
t0 = time.perf_counter()
exact = wf.sweep([truth_b], speeds, positions, contact="3d", track=track,
                 config=dataclasses.replace(config, contact_mode_3d="table"), progress=False)
clean = exact.max_force[0].max(axis=-1)
measured = clean * (1 + 0.03 * np.random.default_rng(7).standard_normal(clean.size))
t1 = time.perf_counter()
res = fit.fit_flat(fit.MaxForceData(speeds, measured), initial, contact="3d",
                   impact_positions=positions, track=track, config=config, parametrisation=param)
t2 = time.perf_counter()
print({mark!r} + json.dumps({{
    "wfjax_file": wf.__file__, "import_s": t0 - t_start, "truth_s": t1 - t0,
    "fit_s": t2 - t1, "iterations": int(res.n_iterations), "converged": bool(res.converged),
    "message": str(res.message), "depth_mm": float(res.params["depth"]) * 1e3,
    "length_mm": float(res.params["length"]) * 1e3,
    "measured_kN": [float(x) / 1e3 for x in measured]}}), flush=True)
"""

GRADIENT = """
import dataclasses, json, statistics, time
t_start = time.perf_counter()
import jax, jax.numpy as jnp, numpy as np
import wfjax as wf
from wfjax import fit
t0 = time.perf_counter()
config = dataclasses.replace(wf.SimConfig(), contact_element={element})
speeds = np.linspace(30.0, 140.0, {n_speeds}) / 3.6
init = wf.Flat.rounded(0.9e-3, 0.1)
par = fit.parametrisation_for(init)
theta = jnp.asarray(par.from_flat(init))
ref = dataclasses.replace(init, extent_bound=par.extent_bound)
plain = fit.max_force_model(speeds, ref, "3d", impact_positions=[0.1], config=config)
adjoint = fit.max_force_model(speeds, ref, "3d", impact_positions=[0.1], config=config,
                              adjoint=True)
data = jnp.asarray(np.asarray(plain(par.to_flat(theta * 1.02))))
t1 = time.perf_counter()
def misfit(model):
    return lambda th: jnp.mean(((model(par.to_flat(th)) - data) / 2e5) ** 2)
forward = jax.jit(misfit(plain))
gradient = jax.jit(jax.value_and_grad(misfit(adjoint)))
def timed(fn):
    c0 = time.perf_counter()
    out = jax.block_until_ready(fn(theta))
    return time.perf_counter() - c0, out
first_forward, _ = timed(forward)
first_gradient, (value, grad) = timed(gradient)
timed(forward), timed(gradient)  # the unrecorded warm-up round
fwd, grd = [], []
for _ in range({repeats}):
    fwd.append(timed(forward)[0])
    grd.append(timed(gradient)[0])
print({mark!r} + json.dumps({{
    "wfjax_file": wf.__file__, "import_s": t0 - t_start, "setup_s": t1 - t0,
    "first_forward_s": first_forward, "first_gradient_s": first_gradient,
    "forward_s": fwd, "gradient_s": grd,
    "ratio": statistics.median(g / f for f, g in zip(fwd, grd)),
    "forward_median_s": statistics.median(fwd), "gradient_median_s": statistics.median(grd),
    "loss": float(value), "grad": [float(x) for x in np.asarray(grad)]}}), flush=True)
"""

ROUGH = """
import json, time
t_start = time.perf_counter()
import numpy as np
import wfjax as wf
R = wf.roughness
t0 = time.perf_counter()
flat = wf.Flat.rounded(depth=0.9e-3, length=0.1)
rough = R.generate(R.ISO3095_LIMIT, 0, 4.0, x_start=-2.0, n_realisations={n})
times = []
for _ in range(2):
    c0 = time.perf_counter()
    res = wf.sweep(flat, [100.0 / 3.6], impact_positions=[0.1], contact="3d",
                   roughness=rough, progress=False)
    times.append(time.perf_counter() - c0)
print({mark!r} + json.dumps({{
    "wfjax_file": wf.__file__, "import_s": t0 - t_start, "cold_s": times[0],
    "warm_s": times[1], "p50_p95_p99_kN": (res.percentiles()[0, 0] / 1e3).tolist()}}),
    flush=True)
"""

CHECK = "import json, wfjax; print({mark!r} + json.dumps({{'wfjax_file': wfjax.__file__}}))"


# ---------------------------------------------------------------------------- the trees


def _git(*args: str, cwd: Path = REPO) -> str:
    return subprocess.run(["git", *args], cwd=cwd, check=True, capture_output=True,
                          text=True).stdout.strip()


def ensure_old_tree(path: Path, commit: str) -> str:
    """The worktree of ``commit`` at ``path`` (made if missing); returns its full commit."""
    want = _git("rev-parse", f"{commit}^{{commit}}")
    if not path.exists():
        print(f"git worktree add --detach {path} {commit}", file=sys.stderr)
        _git("worktree", "add", "--detach", str(path), commit)
    have = _git("rev-parse", "HEAD", cwd=path)
    if have != want:
        raise SystemExit(f"{path} is at {have[:10]}, not {commit} ({want[:10]}): remove it "
                         f"(git worktree remove {path}) or pass another --old")
    if _git("status", "--porcelain", "--", "wfjax", cwd=path):
        raise SystemExit(f"{path} has local changes under wfjax/")
    return have


def fingerprint(path: Path) -> str:
    """HEAD, the diff of wfjax/ against it and its untracked files (names, sizes, mtimes):
    changes when someone edits the tree while the benchmark runs."""
    import hashlib

    try:
        parts = [_git("rev-parse", "HEAD", cwd=path), _git("diff", "HEAD", "--", "wfjax",
                                                           cwd=path)]
        for name in _git("ls-files", "-o", "--exclude-standard", "--", "wfjax",
                         cwd=path).splitlines():
            st = (path / name).stat()
            parts.append(f"{name} {st.st_size} {st.st_mtime_ns}")
    except (subprocess.CalledProcessError, OSError):
        return "?"
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:16]


def tree_info(path: Path) -> dict:
    info = {"path": str(path), "fingerprint": fingerprint(path)}
    try:
        info["commit"] = _git("rev-parse", "HEAD", cwd=path)
        info["wfjax_changes"] = _git("status", "--porcelain", "--", "wfjax", cwd=path)
    except subprocess.CalledProcessError:
        pass
    return info


# ---------------------------------------------------------------------------- running


def _env(tree: Path, cache: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree), WFJAX_CACHE_DIR=str(cache))
    env.pop("PYTHONSTARTUP", None)
    return env


def _cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _result(stdout: str) -> dict | None:
    for line in reversed(stdout.splitlines()):
        if line.startswith(MARK):
            return json.loads(line[len(MARK):])
    return None


def run_timed(cmd: list[str], tree: Path, cache: Path, cwd: Path, timeout: float) -> dict:
    """Run ``cmd`` (``PYTHONPATH=tree``, ``WFJAX_CACHE_DIR=cache``, in ``cwd``): wall and
    CPU time (user + system of the process and its children), exit status, marked result."""
    load = os.getloadavg()[0]
    c0, t0 = _cpu_children(), time.perf_counter()
    try:
        p = subprocess.run(cmd, env=_env(tree, cache), cwd=cwd, capture_output=True,
                           text=True, timeout=timeout, check=False)
        rc, out, err = p.returncode, p.stdout, p.stderr
    except subprocess.TimeoutExpired as exc:
        rc, out, err = -9, str(exc.stdout or ""), f"timeout after {timeout} s"
    wall, cpu = time.perf_counter() - t0, _cpu_children() - c0
    run = {"wall_s": wall, "cpu_s": cpu, "rc": rc, "load_before": load,
           "load_after": os.getloadavg()[0], "result": _result(out)}
    if rc != 0:
        run["stderr_tail"] = (err or out)[-3000:]
    return run


def check_import(tree: Path, timeout: float = 120) -> str:
    """The ``wfjax`` a subprocess imports with ``PYTHONPATH=tree``: must be the tree's."""
    with tempfile.TemporaryDirectory(prefix="wfjax-i30-") as tmp:
        run = run_timed([sys.executable, "-c", CHECK.format(mark=MARK)], tree, Path(tmp),
                        Path(tmp), timeout)
    found = (run["result"] or {}).get("wfjax_file", "")
    if not Path(found).resolve().is_relative_to(tree.resolve()):
        raise SystemExit(f"PYTHONPATH={tree}: imported {found!r} instead "
                         f"({run.get('stderr_tail', '')})")
    return found


def _wfjax_cli() -> list[str]:
    """The venv's ``wfjax`` console script (as the README runs it), else ``-m wfjax.cli``."""
    script = Path(sys.executable).with_name("wfjax")
    return [str(script)] if script.exists() else [sys.executable, "-m", "wfjax.cli"]


def _summary(path: Path, keys=None) -> dict | None:
    """A command's summary JSON (small entries only), to compare the trees' results."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    keep = {}
    for k, v in data.items():
        if keys is not None and k not in keys:
            continue
        if len(json.dumps(v)) <= 2000:
            keep[k] = v
    return keep


def group_main(tree: Path, cache: Path, work: Path, args) -> dict:
    cmd = [*_wfjax_cli(), "sweep"]
    runs = {}
    for label in ("main job cold", "main job warm"):
        r = run_timed(cmd, tree, cache, work, args.timeout)
        r["result"] = _summary(work / "out" / "sweep" / "sweep.json", SUMMARY_KEYS)
        runs[label] = r
    return runs


def group_fig8(tree: Path, cache: Path, work: Path, args) -> dict:
    runs = {}
    for label, name in (("Fig. 8 set cold", "fig8_cold"), ("Fig. 8 set warm", "fig8_warm")):
        out = work / name
        cmd = [*_wfjax_cli(), "figures", "--only", "8", "--out", str(out)]
        if args.quick:
            cmd.append("--fast")
        r = run_timed(cmd, tree, cache, work, args.timeout)
        r["result"] = _summary(out / "fig8.json", SUMMARY_KEYS)
        runs[label] = r
    return runs


def _snippet_check(run: dict, tree: Path) -> None:
    found = (run["result"] or {}).get("wfjax_file")
    if found and not Path(found).resolve().is_relative_to(tree.resolve()):
        raise SystemExit(f"a snippet imported {found}, not the tree {tree}")


def group_fit3d(tree: Path, cache: Path, work: Path, args) -> dict:
    code = FIT3D.format(n_speeds=3 if args.quick else 5, mark=MARK)
    r = run_timed([sys.executable, "-c", code], tree, cache, work, args.timeout)
    _snippet_check(r, tree)
    inner = dict(r, wall_s=r["result"]["fit_s"]) if r["result"] else dict(r, rc=r["rc"] or 1)
    return {"3D fit (fit_flat, incl. family build and compile)": inner,
            "3D fit script (import, truth table, fit)": r}


def group_gradient(tree: Path, cache: Path, work: Path, args) -> dict:
    code = GRADIENT.format(element=2e-3, n_speeds=3 if args.quick else 10,
                           repeats=3 if args.quick else args.grad_repeats, mark=MARK)
    r = run_timed([sys.executable, "-c", code], tree, cache, work, args.timeout)
    _snippet_check(r, tree)
    res = r["result"]
    if not res:
        failed = dict(r, rc=r["rc"] or 1)
        return {RATIO: failed,
                "forward, warm call": failed, "gradient, warm call": failed}
    return {RATIO: dict(r, wall_s=res["ratio"]),
            "forward, warm call": dict(r, wall_s=res["forward_median_s"]),
            "gradient, warm call": dict(r, wall_s=res["gradient_median_s"])}


def group_rough(tree: Path, cache: Path, work: Path, args) -> dict:
    code = ROUGH.format(n=100 if args.quick else 1000, mark=MARK)
    r = run_timed([sys.executable, "-c", code], tree, cache, work, args.timeout)
    _snippet_check(r, tree)
    res = r["result"]
    if not res:
        failed = dict(r, rc=r["rc"] or 1)
        return {"1,000 rough realisations, 3D table, first call": failed,
                "1,000 rough realisations, 3D table, warm call": failed}
    return {"1,000 rough realisations, 3D table, first call": dict(r, wall_s=res["cold_s"]),
            "1,000 rough realisations, 3D table, warm call": dict(r, wall_s=res["warm_s"])}


RUNNERS = {"main": group_main, "fig8": group_fig8, "fit3d": group_fit3d,
           "gradient": group_gradient, "rough": group_rough}


# ---------------------------------------------------------------------------- report


def summarise(runs: list[dict]) -> dict:
    """Per measurement: both trees' values by round, the paired ratios new/old, medians."""
    table: dict = {}
    old_first: dict = {}
    for r in runs:
        m = table.setdefault(r["measurement"], {"old": {}, "new": {}})
        if r["rc"] == 0:
            m[r["tree"]][r["round"]] = r["wall_s"]
        if r["tree"] == "old":
            old_first[r["round"]] = r["first"]
    out = {}
    for name, m in table.items():
        paired = sorted(set(m["old"]) & set(m["new"]))
        ratios = [m["new"][k] / m["old"][k] for k in paired]
        out[name] = {
            "old": [m["old"][k] for k in sorted(m["old"])],
            "new": [m["new"][k] for k in sorted(m["new"])],
            "ratios_new_over_old": ratios,
            "old_median": statistics.median(m["old"].values()) if m["old"] else None,
            "new_median": statistics.median(m["new"].values()) if m["new"] else None,
            "paired_median_ratio": statistics.median(ratios) if ratios else None,
            "order_balanced_ratio": _balanced(paired, ratios, old_first),
            "rounds": len(ratios),
        }
    return out


def _balanced(rounds: list, ratios: list, old_first: dict):
    """exp of the mean of the two orders' mean log ratios (old first, new first): the second
    run of a pair is measured slower on this machine, and with an odd number of rounds the
    plain median leans to the order that ran more often."""
    by = {True: [], False: []}
    for k, ratio in zip(rounds, ratios, strict=True):
        by[old_first[k]].append(math.log(ratio))
    if not by[True] or not by[False]:
        return None
    return math.exp(0.5 * (statistics.mean(by[True]) + statistics.mean(by[False])))


def markdown(summary: dict) -> str:
    def f(x, fmt):
        return "-" if x is None else format(x, fmt)

    lines = ["| measurement | old median [s] | new median [s] | paired median ratio new/old "
             "| order-balanced ratio | ratios per round | rounds |",
             "| --- | ---: | ---: | ---: | ---: | --- | ---: |"]
    for name, s in summary.items():
        small = s["old_median"] is not None and s["old_median"] < 1
        fmt = ".3f" if small or name == RATIO else ".1f"
        lines.append(f"| {name} | {f(s['old_median'], fmt)} | {f(s['new_median'], fmt)} | "
                     f"**{f(s['paired_median_ratio'], '.3f')}** | "
                     f"{f(s.get('order_balanced_ratio'), '.3f')} | "
                     f"{', '.join(format(x, '.2f') for x in s['ratios_new_over_old'])} | "
                     f"{s['rounds']} |")
    return "\n".join(lines)


def _short(run: dict, label: str) -> str:
    if run["rc"] != 0:
        return f"FAILED rc={run['rc']}"
    if label == RATIO:
        return f"{run['wall_s']:.3f}x"
    return f"{run['wall_s']:.3f} s" if run["wall_s"] < 1 else f"{run['wall_s']:.1f} s"


# ---------------------------------------------------------------------------- main


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--old", type=Path, default=Path("/tmp/wfjax-old"),
                   help="worktree of the old commit (made if missing; default /tmp/wfjax-old)")
    p.add_argument("--old-commit", default=OLD_COMMIT, help="default %(default)s")
    p.add_argument("--new", type=Path, default=REPO, help="new tree (default: this repository)")
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--first-round", type=int, default=1,
                   help="number of the first round (its parity sets who runs first: odd old)")
    p.add_argument("--merge", type=Path, nargs="+",
                   help="print the summary of these JSON files' runs together and exit")
    p.add_argument("--only", default=",".join(GROUPS),
                   help="groups to run, comma separated (default %(default)s)")
    p.add_argument("--quick", action="store_true",
                   help="smaller Fig. 8 set, fit and gradient (smoke test, not for the record)")
    p.add_argument("--grad-repeats", type=int, default=7,
                   help="timed forward/gradient pairs per gradient run (default %(default)s)")
    p.add_argument("--timeout", type=float, default=1800, help="per run [s]")
    p.add_argument("--json", type=Path, default=REPO / "benchmarks/results/bench_issue30.json")
    args = p.parse_args(argv)
    args.groups = [g.strip() for g in args.only.split(",") if g.strip()]
    bad = [g for g in args.groups if g not in GROUPS]
    if bad:
        p.error(f"--only: unknown group(s) {bad}; choose from {','.join(GROUPS)}")
    return args


def merged(paths: list[Path]) -> None:
    """Print the summary of several runs' JSON files together (e.g. an extra round)."""
    runs = [r for p in paths for r in json.loads(p.read_text())["runs"]]
    print(markdown(summarise(runs)))


def main(argv=None) -> None:
    args = parse_args(argv)
    if args.merge:
        merged(args.merge)
        return
    old_commit = ensure_old_tree(args.old, args.old_commit)
    trees = {"old": args.old.resolve(), "new": args.new.resolve()}
    report = {
        "issue": 30, "started": time.strftime("%Y-%m-%d %H:%M:%S %z"),
        "argv": sys.argv[1:], "python": sys.executable, "cpu_count": os.cpu_count(),
        "quick": args.quick, "groups": args.groups, "rounds": args.rounds,
        "trees": {"old": dict(tree_info(trees["old"]), requested=args.old_commit,
                              commit=old_commit),
                  "new": tree_info(trees["new"])},
        "env": {k: v for k, v in os.environ.items() if k.startswith(("XLA_", "JAX_"))},
        "runs": [],
    }
    for name, tree in trees.items():
        found = check_import(tree)
        report["trees"][name]["imports"] = found
        # byte-compile both trees first, so neither pays it inside a timed run
        subprocess.run([sys.executable, "-m", "compileall", "-q", str(tree / "wfjax")],
                       check=False, capture_output=True)
        print(f"{name}: {tree} ({report['trees'][name].get('commit', '?')[:10]}), "
              f"imports {found}", file=sys.stderr)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    t_all = time.perf_counter()
    for rnd in range(args.first_round - 1, args.first_round - 1 + args.rounds):
        order = ("old", "new") if rnd % 2 == 0 else ("new", "old")
        t_round = time.perf_counter()
        for group in args.groups:
            for position, name in enumerate(order):
                work = Path(tempfile.mkdtemp(prefix=f"wfjax-i30-{name}-{group}-"))
                cache = work / "cache"
                cache.mkdir()
                try:
                    runs = RUNNERS[group](trees[name], cache, work, args)
                finally:
                    shutil.rmtree(work, ignore_errors=True)
                shown = set()
                for label, run in runs.items():
                    report["runs"].append(dict(run, round=rnd + 1, group=group,
                                               measurement=label, tree=name,
                                               first=position == 0))
                    print(f"[round {rnd + 1}/{args.rounds}] {label}: {name} {_short(run, label)} "
                          f"(cpu {run['cpu_s']:.1f} s, load {run['load_before']:.1f})",
                          file=sys.stderr, flush=True)
                    tail = run.get("stderr_tail") if run["rc"] != 0 else None
                    if tail and tail not in shown:  # a group's measurements share a process
                        shown.add(tail)
                        print(tail[-1500:], file=sys.stderr)
            report["summary"] = summarise(report["runs"])
            args.json.write_text(json.dumps(report, indent=1))
        print(f"[round {rnd + 1}/{args.rounds}] took {time.perf_counter() - t_round:.0f} s",
              file=sys.stderr, flush=True)
    report["total_s"] = time.perf_counter() - t_all
    for name, tree in trees.items():
        end = fingerprint(tree)
        report["trees"][name]["fingerprint_at_end"] = end
        if end != report["trees"][name]["fingerprint"]:
            print(f"WARNING: the {name} tree {tree} changed while the benchmark ran (HEAD, "
                  f"wfjax/ diff or untracked files); pin it with a worktree: "
                  f"git worktree add --detach /tmp/wfjax-new HEAD; --new /tmp/wfjax-new",
                  file=sys.stderr)
    report["summary"] = summarise(report["runs"])
    args.json.write_text(json.dumps(report, indent=1))
    print(f"### Issue 30: old {old_commit[:7]} vs new "
          f"{report['trees']['new'].get('commit', '?')[:7]}"
          f"{' + local changes' if report['trees']['new'].get('wfjax_changes') else ''}, "
          f"{args.rounds} interleaved round(s){' (--quick)' if args.quick else ''}\n")
    print(markdown(report["summary"]))
    print(f"\n(JSON: {args.json})")


if __name__ == "__main__":
    main()

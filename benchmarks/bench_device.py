"""One benchmark for whatever JAX backend is present (CPU, GPU, TPU): time, memory, float32.

Sections (``--sections``, all by default):

* ``default``: the default ``wfjax sweep`` (rounded 0.9 mm/100 mm and new 0.9 mm flats,
  29 speeds 20-300 km/h, 10 positions = 580 runs, 3D exact tables, R_R = 0.30 m);
* ``fig7``: the paper's Fig. 7 set (the same flats, speeds and positions, R_R = 0.45 m);
* ``fig8``: the Fig. 8 set (8 rounded flats 0.25-2.00 mm, l = 1.76 l0, x 29 speeds x
  8 positions = 1856 runs, 3D through the parametric family, R_R = 0.45 m);
* ``large-hertz``, ``large-3d``: a large batch, depths x speeds x positions (rounded flats
  over the Fig. 8 depths, l = 1.76 l0; 25 speeds 50-290 km/h, 8 positions; ``--large-runs``,
  default 100,000, rounded up to whole depths), Hertz-trajectory and 3D (parametric family);
* ``table``: one exact 3D table build (rounded 0.9 mm/100 mm, R_R = 0.30 m, 1 mm elements),
  with the backend's column batch (``table_law.table_batch_size``);
* ``gradient``: one forward-mode gradient (``jacfwd``, depth and length: what ``fit_flat``
  uses) of a 10-speed max-force misfit, Hertz-trajectory, 1 impact position;
* ``train`` (only when named in ``--sections``): the identification issue's train,
  ``benchmarks/identify_train.py`` (20 wagons, 80 wheels; ``--quick`` 2, ``--tiny`` 1 with a
  smoke-size response table) in its own processes: the truth, ``identify`` from an empty
  cache (cold) and again on the cache that left (warm), and the flags against the truth.

For each sweep, table or gradient section: the first call's compile time
(``jax.monitoring`` compile events) and the rest of its setup (modal model, tables or family
from the disk cache or built), the run time of a second, compiled call, runs per second, the
peak memory so far (GPU/TPU: ``peak_bytes_in_use`` of device 0; CPU: the process's peak RSS;
both only grow, so the default order runs from small to large), and float32 against float64
(``SimConfig.precision``): run-time ratio and the largest relative difference of the max
force over all runs, and the loss-of-contact speeds per flat (lowest speed with loss of
contact at any position) where they differ. The table build runs in float64 only (setup is
float64 by design); the gradient's difference is the largest over its components, relative
to the largest. A section that fails is reported as failed and the others still run (exit
code 1).

Run: ``python benchmarks/bench_device.py [--quick | --tiny] [--json out.json]
[--host-devices N]`` (CPU: one JAX device per core by default, as the ``wfjax`` command; GPUs
are used as they are). ``--quick``
shrinks every section (fewer speeds, positions and depths, 2 mm contact elements; under
5 minutes on a 2-core CPU with a cold cache); ``--tiny`` is the
CI smoke test's size (``tests/test_device.py``). Sections run in the order named; the JSON
(``--json``) is rewritten after every section, so a run cut short keeps what it finished.
Prints one Markdown table (and the train's line) and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import wfjax as wf
from wfjax import fit
from wfjax._compile_clock import compile_seconds
from wfjax.cli import expose_cpu_cores
from wfjax.commands.figures import fig7_flats
from wfjax.contact import table_law, table_spec, tables
from wfjax.program import grid

SECTIONS = ("table", "gradient", "default", "fig7", "fig8", "large-hertz", "large-3d")
OPTIONAL_SECTIONS = ("train",)  # run only when named
TRAIN = {"full": (20, "{}"), "quick": (2, "{}"),  # wagons, response-table options (JSON)
         "tiny": (1, '{"n_offsets": 2, "n_roughness": 1}')}
# per size: speeds [km/h], positions, Fig. 8 depths [mm], 3D element [m], table element [m],
# gradient speeds, large-batch speeds and positions
SIZES = {
    "full": dict(speeds=np.arange(20.0, 301.0, 10.0), positions=10, positions8=8,
                 depths8=np.arange(0.25, 2.01, 0.25), element=1e-3, table_element=1e-3,
                 grad_speeds=10, large_speeds=np.arange(50.0, 291.0, 10.0), large_positions=8),
    "quick": dict(speeds=np.arange(40.0, 281.0, 40.0), positions=2, positions8=2,
                  depths8=np.array([0.5, 1.0]), element=2e-3, table_element=2e-3,
                  grad_speeds=4, large_speeds=np.arange(50.0, 291.0, 30.0), large_positions=4),
    "tiny": dict(speeds=np.array([60.0, 200.0]), positions=1, positions8=1,
                 depths8=np.array([0.5, 1.0]), element=2e-3, table_element=2e-3,
                 grad_speeds=2, large_speeds=np.array([60.0, 200.0]), large_positions=1),
}
LARGE_RUNS = {"full": 100_000, "quick": 600, "tiny": 8}


def peak_memory_mib() -> tuple[float, str]:
    """(peak memory so far [MiB], what it measures)."""
    stats = jax.devices()[0].memory_stats() or {}
    if "peak_bytes_in_use" in stats:
        return stats["peak_bytes_in_use"] / 2**20, "device peak_bytes_in_use"
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "process peak RSS"


def timed(fn):
    """(result, wall [s], compile [s]) of ``fn()``, blocked until ready."""
    c0, t0 = compile_seconds(), time.perf_counter()
    out = jax.block_until_ready(fn())
    return out, time.perf_counter() - t0, compile_seconds() - c0


def loss_speeds(result) -> list:
    """Lowest speed [km/h] with loss of contact at any position, per flat (None: none)."""
    return [None if math.isnan(v) else round(v * 3.6, 6) for v in
            (wf.sweeps.loss_of_contact_speed(result, i) for i in range(len(result.flats)))]


def sweep_section(flats, speeds_kmh, positions, contact, track, element):
    """A ``run(precision) -> (max_force [runs], loss speeds)`` for one sweep, and its runs."""
    def run(precision):
        res = wf.sweep(flats, speeds_kmh / 3.6, positions, contact=contact, track=track,
                       config=wf.SimConfig(contact_element=element, precision=precision),
                       progress=False)
        return np.asarray(res.max_force).ravel(), loss_speeds(res)

    return run, len(flats) * speeds_kmh.size * positions


def large_flats(n_runs: int, size: dict) -> list:
    """Rounded flats (l = 1.76 l0) evenly over the Fig. 8 depths, enough for ``n_runs``."""
    per_depth = size["large_speeds"].size * size["large_positions"]
    n = max(2, -(-n_runs // per_depth))
    depths = np.linspace(size["depths8"].min(), size["depths8"].max(), n)
    return [wf.Flat.rounded_relative(d * 1e-3, 1.76) for d in depths]


def gradient_section(n_speeds: int):
    """One jacfwd of a max-force misfit (as ``benchmarks/bench_fit.py``), per precision."""
    speeds = np.linspace(30.0, 140.0, n_speeds) / 3.6
    par = fit.RoundedFlatParam(extent_bound=0.075)
    theta = jnp.asarray(par.from_flat(wf.Flat.rounded(0.9e-3, 0.1)))
    ref = jax.tree_util.tree_map(np.asarray, par.to_flat(theta))
    programs = {}

    def run(precision):
        if precision not in programs:
            model = fit.max_force_model(speeds, ref, "hertz-trajectory", impact_positions=[0.1],
                                        config=wf.SimConfig(precision=precision))
            data = np.full(n_speeds, 250e3)  # "measured" max forces [N]

            def misfit_grad(th):
                def residuals(t):
                    r = (model(par.to_flat(t)) - data) / 2e5
                    return r, r

                J, r = jax.jacfwd(residuals, has_aux=True)(th)
                return 2 * J.T @ r / r.size

            programs[precision] = jax.jit(misfit_grad)
        return np.asarray(programs[precision](theta)), None

    return run, n_speeds


def table_section(element: float):
    flat = wf.Flat.rounded(0.9e-3, 0.1)
    batch = table_law.table_batch_size()
    spec = table_spec.table_spec(flat, 0.45, 0.30, wf.Material(), element)

    def run(precision):
        t = tables.build_table_3d(flat, 0.45, 0.30, spec=spec, batch_size=batch)
        return np.asarray(t.force).ravel(), None

    return run, spec.n_s // 2 + 1, f"batch_size {batch}, {spec.n_s} x {spec.n_t} nodes"


def measure(name: str, run, n_runs: int, note: str = "", float32: bool = True) -> dict:
    row = {"section": name, "runs": n_runs, "note": note}
    results = {}
    for precision in ("float64", "float32") if float32 else ("float64",):
        (first, loss), wall1, comp = timed(lambda p=precision: run(p))
        (second, _), wall2, comp2 = timed(lambda p=precision: run(p))
        results[precision] = (second, loss)
        row[precision] = {"first_call_s": wall1, "compile_s": comp,
                          "setup_s": max(0.0, wall1 - comp - wall2), "run_s": wall2,
                          "recompile_s": comp2, "runs_per_s": n_runs / wall2,
                          "loss_of_contact_kmh": loss}
        row["peak_mib"], row["peak_of"] = peak_memory_mib()
    if float32:
        f64, f32 = results["float64"][0], results["float32"][0]
        scale = np.abs(f64) if name != "gradient" else np.max(np.abs(f64))
        row["f32_time_ratio"] = row["float32"]["run_s"] / row["float64"]["run_s"]
        row["f32_max_rel_diff"] = float(np.max(np.abs(f32 - f64) / scale))
        row["loss_speed_changed"] = results["float32"][1] != results["float64"][1]
    print(f"  {name}: done ({json.dumps(_brief(row))})", file=sys.stderr, flush=True)
    return row


def _brief(row: dict) -> dict:
    return {k: (float(f"{v:.3g}") if isinstance(v, float) else v) for k, v in row.items()
            if k in ("runs", "f32_time_ratio", "f32_max_rel_diff")} | {
        "run_s": round(row["float64"]["run_s"], 3)}


def train_section(size_name: str) -> dict:
    """``benchmarks/identify_train.py`` at this size, in its own processes: a row of times
    [s] (truth, cold and warm ``identify``) and flags against the truth."""
    wagons, options = TRAIN[size_name]
    work = Path(tempfile.mkdtemp(prefix="bench_train_"))
    out = work / "train.json"
    cmd = [sys.executable, str(Path(__file__).with_name("identify_train.py")), "--wagons",
           str(wagons), "--table-options", options, "--work-dir", str(work), "--out", str(out)]
    if wagons < 20:
        cmd += ["--flats", "1:new:60"]
    subprocess.run(cmd, check=True)
    res = json.loads(out.read_text())
    t, s = res["times"], res["score"]
    row = {"section": "train", "runs": res["meta"]["n_wheels"], "note": f"{wagons} wagons",
           "truth_s": t["truth_s"], "identify_cold_s": t["identify_cold_s"],
           "identify_warm_s": t["identify_warm_s"], "score": s,
           "cold_and_warm_answers_equal": res["meta"]["cold_and_warm_answers_equal"]}
    row["peak_mib"], row["peak_of"] = peak_memory_mib()  # this process only
    times = {k: row[k] for k in ("truth_s", "identify_cold_s", "identify_warm_s")}
    print(f"  train: done ({json.dumps(times)})", file=sys.stderr, flush=True)
    return row


def train_markdown(row: dict) -> str:
    """One line: the train's times [s] and flags."""
    s = row["score"]
    return (f"train ({row['note']}, {row['runs']} wheels): truth {row['truth_s']:.1f} s, "
            f"identify cold {row['identify_cold_s']:.1f} s, warm {row['identify_warm_s']:.1f} s;"
            f" flats flagged {s['flats_flagged']} of {s['n_flats']}, round wheels flagged "
            f"{len(s['round_flagged'])} of {s['n_round']}")


def table_markdown(rows: list[dict]) -> str:
    lines = ["| section | runs | setup [s] | compile [s] | run [s] | runs/s | peak [MiB] | "
             "f32/f64 time | f32 max rel. diff | loss speeds |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['section']} | failed: {r['error'][:80]} |")
            continue
        if r["section"] == "train":
            continue
        d = r["float64"]
        if "f32_time_ratio" in r:
            f32 = (f"{r['f32_time_ratio']:.2f}", f"{r['f32_max_rel_diff']:.1e}",
                   "changed" if r["loss_speed_changed"] else "same")
        else:
            f32 = ("-", "-", "-")
        lines.append(f"| {r['section']} | {r['runs']} | {d['setup_s']:.1f} | "
                     f"{d['compile_s']:.1f} | {d['run_s']:.2f} | {d['runs_per_s']:.3g} | "
                     f"{r['peak_mib']:.0f} | {' | '.join(f32)} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    size_group = p.add_mutually_exclusive_group()
    size_group.add_argument("--quick", action="store_true", help="every section smaller")
    size_group.add_argument("--tiny", action="store_true", help="smoke-test size (CI)")
    p.add_argument("--sections", default=",".join(SECTIONS),
                   help=f"comma-separated, run in this order: {','.join(SECTIONS)} and "
                   f"{','.join(OPTIONAL_SECTIONS)} (only when named)")
    p.add_argument("--large-runs", type=int, help="runs of the large batch (default 100000; "
                   "--quick 600)")
    p.add_argument("--json", default="bench_device.json", help="where to write the JSON")
    p.add_argument("--host-devices", type=int, help="CPU devices (default: one per core, as "
                   "the wfjax command; no effect once JAX's backend is initialised)")
    args = p.parse_args(argv)
    expose_cpu_cores(args.host_devices)
    size_name = "tiny" if args.tiny else "quick" if args.quick else "full"
    size = SIZES[size_name]
    wanted = [s.strip() for s in args.sections.split(",") if s.strip()]
    bad = sorted(set(wanted) - set(SECTIONS + OPTIONAL_SECTIONS))
    if bad or not wanted or len(set(wanted)) < len(wanted):
        p.error(f"--sections: unknown or repeated in {args.sections!r}; choose from "
                f"{','.join(SECTIONS + OPTIONAL_SECTIONS)}")
    n_large = args.large_runs or LARGE_RUNS[size_name]
    if n_large < 1:
        p.error(f"--large-runs must be >= 1, got {n_large}")
    el, speeds, pos = size["element"], size["speeds"], size["positions"]
    comparison = wf.Track.comparison()
    flats7 = fig7_flats()
    makers = {
        "table": lambda: table_section(size["table_element"]),
        "gradient": lambda: (*gradient_section(size["grad_speeds"]), "jacfwd, 2 parameters"),
        "default": lambda: (*sweep_section(flats7, speeds, pos, "3d", wf.Track(), el),
                            "R_R = 0.30 m, exact tables"),
        "fig7": lambda: (*sweep_section(flats7, speeds, pos, "3d", comparison, el),
                         "R_R = 0.45 m, exact tables"),
        "fig8": lambda: (*sweep_section([wf.Flat.rounded_relative(d * 1e-3, 1.76)
                                         for d in size["depths8"]], speeds,
                                        size["positions8"], "3d", comparison, el),
                         "parametric family"),
        "large-hertz": lambda: (*sweep_section(
            large_flats(n_large, size), size["large_speeds"], size["large_positions"],
            "hertz-trajectory", comparison, el), "depths x speeds x positions"),
        "large-3d": lambda: (*sweep_section(
            large_flats(n_large, size), size["large_speeds"], size["large_positions"], "3d",
            comparison, el), "depths x speeds x positions, parametric family"),
    }
    device = jax.devices()[0]
    header = {"backend": jax.default_backend(), "device": str(device.device_kind),
              "device_count": jax.device_count(), "jax": jax.__version__,
              "wfjax": wf.__version__, "size": size_name, "host": platform.processor() or
              platform.machine(), "cpu_count": os.cpu_count(),
              "load_average": os.getloadavg(), "chunk_width_per_device": None}
    print(f"bench_device: {header['backend']} ({header['device']}) x "
          f"{header['device_count']}, size {size_name}, load {os.getloadavg()[0]:.1f}",
          file=sys.stderr)
    header["chunk_width_per_device"] = grid.chunk_width(3000, 599)
    rows = []
    for name in wanted:
        try:
            if name == "train":
                rows.append(train_section(size_name))
            else:
                run, n_runs, note = makers[name]()
                rows.append(measure(name, run, n_runs, note, float32=name != "table"))
        except Exception as exc:  # one section's failure must not cost the others
            traceback.print_exc()
            rows.append({"section": name, "error": f"{type(exc).__name__}: {exc}"})
        header["load_average_end"] = os.getloadavg()
        Path(args.json).write_text(json.dumps({"header": header, "rows": rows}, indent=1))
    print(f"\n{header['backend']} ({header['device']}) x {header['device_count']}, "
          f"size {size_name}, load average {header['load_average'][0]:.1f} -> "
          f"{header['load_average_end'][0]:.1f}; peak memory = "
          f"{next((r['peak_of'] for r in rows if 'peak_of' in r), '-')}\n")
    print(table_markdown(rows))
    for row in rows:
        if row["section"] == "train" and "error" not in row:
            print("\n" + train_markdown(row))
    return 1 if any("error" in r for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())

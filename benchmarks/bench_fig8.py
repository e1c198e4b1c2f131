"""The Fig. 8 set with the parametric 3D law: time, memory, and accuracy against exact tables.

Fig. 8: rounded flats l = 1.76 l0, depths 0.25-2.00 mm (step 0.25), 29 speeds (20-300 km/h),
8 impact positions, R_W = R_R = 0.45 m, 3D contact. ``wf.sweep`` runs the 8 flats as one batch
through the parametric family F(delta, s; depth, length) (one compile).

* ``cold``: a fresh cache directory (modal model and family built), timed end to end, one
  JAX device per core as the ``wfjax`` command uses;
* ``warm``: the same sweep again in a new process on the now-filled cache (contact family and
  the persistent XLA compilation cache, as ``wfjax figures`` uses them);
* ``--accuracy``: the same runs with each flat's exact per-flat table
  (``SimConfig(contact_mode_3d="table")``, 8 builds), with identical simulation windows (every
  flat carries the batch's ``extent_bound``), so the difference is the law's alone: the largest
  relative difference of the max force over all 1856 runs and the loss-of-contact speeds
  (lowest speed of the 10 km/h grid with loss of contact at any position) per depth.

Run: ``python benchmarks/bench_fig8.py [--accuracy] [--quick]``. Prints Markdown, writes
``benchmarks/fig8_accuracy.json`` with ``--accuracy``. Peak memory is the process's
``ru_maxrss``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

DEPTHS_MM = np.arange(0.25, 2.01, 0.25)
SPEEDS_KMH = np.arange(20.0, 301.0, 10.0)


def _peak_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def fig8_flats(depths_mm):
    """The Fig. 8 flats, all with the batch's window bound (identical windows per mode)."""
    from wfjax.commands.figures import fig8_flats as paper_flats
    from wfjax.program.laws import common_extent

    return common_extent(paper_flats(depths_mm))


def run_sweep(mode: str, depths_mm, speeds_kmh, positions: int):
    import wfjax as wf

    t0 = time.perf_counter()
    res = wf.sweep(fig8_flats(depths_mm), speeds_kmh / 3.6, positions, contact="3d",
                   track=wf.Track.comparison(), config=wf.SimConfig(contact_mode_3d=mode),
                   progress=True)
    return res, time.perf_counter() - t0


def _child(args) -> None:
    from wfjax.cli import enable_compilation_cache

    enable_compilation_cache()  # as the wfjax command: compiled programs cached next to tables
    res, elapsed = run_sweep("auto", DEPTHS_MM[:args.n_depths], SPEEDS_KMH[::args.speed_stride],
                             args.positions)
    print(json.dumps({"seconds": elapsed, "peak_mib": _peak_mib(),
                      "max_force": np.asarray(res.max_force).tolist()}))


def _in_fresh_process(cache: str, args) -> dict:
    env = dict(os.environ, WFJAX_CACHE_DIR=cache)
    cmd = [sys.executable, __file__, "--child", "--n-depths", str(args.n_depths),
           "--speed-stride", str(args.speed_stride), "--positions", str(args.positions)]
    out = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def loss_speeds(result) -> list:
    """Per flat: the lowest speed [km/h] with loss of contact at any position (None if none)."""
    lost = np.any(result.loss_of_contact, axis=-1)
    v = np.asarray(result.speeds) * 3.6
    return [round(float(v[row].min()), 1) if row.any() else None for row in lost]


def main() -> None:
    from wfjax.cli import expose_cpu_cores

    expose_cpu_cores()  # one JAX device per core, as the wfjax command does
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--accuracy", action="store_true",
                   help="also run the exact per-flat tables and compare (minutes)")
    p.add_argument("--quick", action="store_true", help="2 depths, 8 speeds, 2 positions")
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--n-depths", type=int, default=8, help=argparse.SUPPRESS)
    p.add_argument("--speed-stride", type=int, default=1, help=argparse.SUPPRESS)
    p.add_argument("--positions", type=int, default=8, help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.quick:
        args.n_depths, args.speed_stride, args.positions = 2, 4, 2
    if args.child:
        _child(args)
        return
    n_runs = args.n_depths * SPEEDS_KMH[::args.speed_stride].size * args.positions
    with tempfile.TemporaryDirectory() as cache:
        cold = _in_fresh_process(cache, args)
        warm = _in_fresh_process(cache, args)
        print(f"### Fig. 8 set, parametric 3D law ({n_runs} runs, {os.cpu_count()} cores)\n")
        print("| run | total [s] | peak RSS [MiB] |")
        print("| --- | --- | --- |")
        for label, r in (("cold (empty cache, new process)", cold),
                         ("warm (filled cache, new process)", warm)):
            print(f"| {label} | {r['seconds']:.1f} | {r['peak_mib']:.0f} |")
        if not args.accuracy:
            return
        os.environ["WFJAX_CACHE_DIR"] = cache
        depths, speeds = DEPTHS_MM[:args.n_depths], SPEEDS_KMH[::args.speed_stride]
        param, _ = run_sweep("parametric", depths, speeds, args.positions)
        exact, t_exact = run_sweep("table", depths, speeds, args.positions)
    rel = np.abs(param.max_force / exact.max_force - 1)
    worst = np.unravel_index(np.argmax(rel), rel.shape)
    lp, le = loss_speeds(param), loss_speeds(exact)
    print(f"\nexact per-flat tables: {t_exact:.1f} s\n")
    print("| depth [mm] | max rel. diff of max force [%] | at speed [km/h] | loss of contact "
          "from, parametric / exact [km/h] |")
    print("| --- | --- | --- | --- |")
    for i, d in enumerate(depths):
        j, k = np.unravel_index(np.argmax(rel[i]), rel[i].shape)
        print(f"| {d:.2f} | {rel[i].max() * 100:.3f} | {speeds[j]:.0f} | {lp[i]} / {le[i]} |")
    report = {
        "depths_mm": depths.tolist(), "speeds_kmh": speeds.tolist(),
        "positions": args.positions, "max_rel_diff": float(rel.max()),
        "worst": {"depth_mm": float(depths[worst[0]]), "speed_kmh": float(speeds[worst[1]]),
                  "position_mm": float(np.asarray(exact.impact_positions)[worst[2]] * 1e3),
                  "parametric_kN": float(param.max_force[worst]) / 1e3,
                  "exact_kN": float(exact.max_force[worst]) / 1e3},
        "loss_of_contact_kmh": {"parametric": lp, "exact": le}, "identical_loss": lp == le,
        "cold_s": cold["seconds"], "warm_s": warm["seconds"], "peak_mib": cold["peak_mib"],
    }
    print(f"\nworst: {report['worst']}; loss-of-contact speeds identical: {lp == le}")
    if not args.quick:
        Path(__file__).with_name("fig8_accuracy.json").write_text(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()

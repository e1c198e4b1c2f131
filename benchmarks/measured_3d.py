"""Measured 3D flats (issue 35): how much the lateral shape matters, and what its table costs.

``speed``: the exact 3D table of the example's measured flat (``wfjax/examples/
measured_sections.csv``, split by :func:`wfjax.scenario.measured.split`) against that of a
``from_profile`` flat of the same extent and grid (its centre line, cut by the rail head's arc;
not mirrored either): each built once to compile, then ``--repeats`` times each, interleaved,
no on-disk cache; the ratio of the medians (``benchmarks/results/measured_3d_speed.json``).
Target: <= 1.5.

``compare``: max contact force (over ``--positions`` impact positions per bay) against speed,
3D contact with the exact tables, the paper's Fig. 7 settings otherwise (Table 2 track with
R_R = R_W = 0.45 m), for the measured surface, its centre-line profile cut by the arc (today's
path), the new flat of the same depth and the rounded flat of the same depth and the shortest
length the paper allows (pi/2 l0; the measured flat is shorter than that). No wheel roughness
(the surface's shape alone). Writes ``benchmarks/results/measured_3d.json`` and
``docs/figures/measured_3d.png``.

Run: ``python benchmarks/measured_3d.py speed`` / ``compare [--speeds-kmh 40,80,...]``.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
from importlib import resources
from pathlib import Path

import numpy as np

import wfjax as wf
from wfjax.contact import tables
from wfjax.contact.table_spec import table_spec
from wfjax.model import geometry
from wfjax.scenario.measured import split
from wfjax.sections import read_records

ROOT = Path(__file__).resolve().parents[1]
LINES_MM = [-20.0, -13.0, -6.0, 0.0, 6.0, 13.0, 20.0]
RR = 0.45


def measured_pair():
    """(measured 3D flat, its centre line as a from_profile flat)."""
    rec = read_records(resources.files("wfjax") / "examples" / "measured_sections.csv",
                       LINES_MM)
    flat = split(rec).flat
    x = np.asarray(flat.profile_x)
    z = np.asarray(geometry.profile_deviation(flat, x))
    return flat, wf.Flat.from_profile(x, z, wheel_radius=float(flat.wheel_radius))


def speed(repeats: int) -> dict:
    flat, profile = measured_pair()
    specs = {k: table_spec(f, 0.45, RR) for k, f in (("sections", flat), ("profile", profile))}
    a, b = specs["sections"], specs["profile"]
    assert (a.nx, a.ny, a.n_s, a.n_t) == (b.nx, b.ny, b.n_s, b.n_t), (a, b)
    times = {"sections": [], "profile": []}
    flats = {"sections": flat, "profile": profile}
    for f in flats.values():  # compile
        tables.build_table_3d(f, 0.45, RR)
    for _ in range(repeats):
        for name, f in flats.items():
            t0 = time.perf_counter()
            tables.build_table_3d(f, 0.45, RR)
            times[name].append(time.perf_counter() - t0)
    med = {k: statistics.median(v) for k, v in times.items()}
    out = {"grid": [a.nx, a.ny, a.n_s, a.n_t], "times_s": times, "median_s": med,
           "ratio": med["sections"] / med["profile"]}
    print(json.dumps(out, indent=1))
    (ROOT / "benchmarks" / "results" / "measured_3d_speed.json").write_text(
        json.dumps(out, indent=1))
    return out


def compare(speeds_kmh, positions: int) -> dict:
    flat, profile = measured_pair()
    d = float(flat.depth)
    l0 = math.sqrt(8 * 0.45 * d)
    flats = {"measured 3D surface": flat, "centre line, arc cut": profile,
             "new, same depth": wf.Flat.new(d),
             "rounded, same depth, l = pi/2 l0": wf.Flat.rounded(d, math.pi / 2 * l0 + 1e-9)}
    v = np.asarray(speeds_kmh, float) / 3.6
    out = {"speeds_kmh": list(map(float, speeds_kmh)), "positions": positions, "depth_mm":
           d * 1e3, "max_force_kN": {}, "seconds": {}}
    for name, f in flats.items():
        t0 = time.perf_counter()
        r = wf.sweep([f], v, positions, contact="3d", track=wf.Track.comparison(),
                     progress=False)
        out["max_force_kN"][name] = (np.asarray(r.max_force)[0].max(axis=-1) / 1e3).tolist()
        out["seconds"][name] = time.perf_counter() - t0
        print(name, np.round(out["max_force_kN"][name], 1), f"{out['seconds'][name]:.0f} s",
              flush=True)
    (ROOT / "benchmarks" / "results" / "measured_3d.json").write_text(json.dumps(out, indent=1))
    _figure(out)
    return out


def _figure(out):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for (name, f), m in zip(out["max_force_kN"].items(), "osd^", strict=True):
        ax.plot(out["speeds_kmh"], f, marker=m, label=name)
    ax.set_xlabel("speed [km/h]")
    ax.set_ylabel("max contact force [kN]")
    ax.set_title(f"3D contact, d = {out['depth_mm']:.2f} mm, R_R = 0.45 m")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(ROOT / "docs" / "figures" / "measured_3d.png", dpi=120)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("what", choices=("speed", "compare"))
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--speeds-kmh", default="40,80,120,160,200,250")
    p.add_argument("--positions", type=int, default=3)
    a = p.parse_args()
    if a.what == "speed":
        speed(a.repeats)
    else:
        compare([float(s) for s in a.speeds_kmh.split(",")], a.positions)


if __name__ == "__main__":
    main()

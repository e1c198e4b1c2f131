"""A 3D fit from an empty cache: the notebook case (notebooks/fit_flat_3d.ipynb, full mode).

Rounded flat 0.9 mm x 100 mm, truth from its exact per-flat 3D table (8 speeds 40-140 km/h,
max over 3 impact positions, 3 % noise, seed 7), start 50 % off (1.35 mm, 150 mm),
R_W = R_R = 0.45 m, 1 mm elements; ``fit_flat(..., contact="3d")`` through the parametric
family. Prints the time of the truth and of the fit (family build included) and the errors.

Run: ``WFJAX_CACHE_DIR=$(mktemp -d) python benchmarks/bench_fit3d.py`` (an empty cache, or the
family is loaded instead of built).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

import wfjax as wf
from wfjax import fit


def main() -> None:
    track, config = wf.Track.comparison(), wf.SimConfig()
    speeds = np.linspace(40.0, 140.0, 8) / 3.6
    truth, initial = wf.Flat.rounded(0.9e-3, 0.1), wf.Flat.rounded(1.35e-3, 0.15)
    param = fit.parametrisation_for(initial)
    t0 = time.perf_counter()
    exact = wf.sweep([dataclasses.replace(truth, extent_bound=param.extent_bound)], speeds, 3,
                     contact="3d", track=track,
                     config=dataclasses.replace(config, contact_mode_3d="table"),
                     progress=False)
    clean = exact.max_force[0].max(axis=-1)
    measured = clean * (1 + 0.03 * np.random.default_rng(7).standard_normal(clean.size))
    t1 = time.perf_counter()
    res = fit.fit_flat(fit.MaxForceData(speeds, measured), initial, contact="3d",
                       impact_positions=3, track=track, config=config, parametrisation=param)
    t2 = time.perf_counter()
    errors = {n: res.params[n] / getattr(truth, n) - 1 for n in ("depth", "length")}
    print(f"truth (exact table) {t1 - t0:.1f} s, fit_flat incl. family {t2 - t1:.1f} s, "
          f"total {t2 - t0:.1f} s; {res.n_iterations} iterations, {res.message}")
    print(", ".join(f"{n} error {100 * e:+.2f} %" for n, e in errors.items()))


if __name__ == "__main__":
    main()

"""Monte Carlo over rail roughness realisations: runs per second of ``sweep(roughness=...)``.

One flat (rounded, 0.9 mm x 100 mm), one speed and impact position, R realisations of an
ISO 3095-limit rail roughness (4 m, 0.25 mm samples) as the batch axis of one compiled
program. The first (cold) call compiles; the figure is the second (warm) call's wall time.
Issue 18's targets on the 2-core CPU: 1,000 realisations with the Hertz-trajectory model in
under 60 s warm, with the 3D table in under 3 minutes.

Run: ``python benchmarks/bench_roughness.py [--realisations 1000] [--contact hertz-trajectory]``.
Prints the times and the load average.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

import wfjax as wf
from wfjax.scenario import roughness as R


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--realisations", type=int, default=1000)
    ap.add_argument("--contact", default="hertz-trajectory")
    ap.add_argument("--speed-kmh", type=float, default=100.0)
    args = ap.parse_args()
    flat = wf.Flat.rounded(depth=0.9e-3, length=0.1)
    rough = R.generate(R.ISO3095_LIMIT, 0, 4.0, x_start=-2.0,
                       n_realisations=args.realisations)
    v = [args.speed_kmh / 3.6]
    times = []
    for _ in range(2):
        t0 = time.perf_counter()
        res = wf.sweep(flat, v, impact_positions=[0.1], contact=args.contact,
                       roughness=rough, progress=False)
        times.append(time.perf_counter() - t0)
    p = res.percentiles()[0, 0] / 1e3
    print(f"{args.contact}, {args.realisations} realisations at {args.speed_kmh:g} km/h: "
          f"cold {times[0]:.1f} s, warm {times[1]:.1f} s "
          f"({args.realisations / times[1]:.0f} runs/s); max force p50/p95/p99 "
          f"{p[0]:.1f} / {p[1]:.1f} / {p[2]:.1f} kN; load average "
          f"{' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    assert np.all(np.isfinite(p))


if __name__ == "__main__":
    main()

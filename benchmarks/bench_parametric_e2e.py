"""Parametric 3D law against exact per-flat tables, end to end, off the Fig. 8 set.

Max force of batched sweeps through the family (``SimConfig(contact_mode_3d="parametric")``)
against each flat's exact table (``"table"``), identical windows
(``wfjax.program.laws.common_extent``),
R_W = R_R = 0.45 m, 1 mm elements, 4 impact positions:

* ``--kind new``: new flats 0.40, 0.75, 1.25, 1.75 mm, 20-300 km/h in 40 km/h steps;
* ``--kind rounded``: rounded flats (0.75 mm, l/l0 1.76), (1.5, 1.76), (0.9, 1.96), (1.2, 2.3)
  at 40, 100, 160, 220 km/h; ``--length-step 0.4`` rebuilds the family on a length-factor
  lattice step of 0.4 instead of 0.2 (``family_spec.LENGTH_FACTOR_STEP``).

Prints the largest relative max-force difference per flat and whether the loss-of-contact
flags agree. Run: ``python benchmarks/bench_parametric_e2e.py [--kind new|rounded]
[--length-step 0.2]`` (minutes; the exact tables are built once, cached).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import wfjax as wf
from wfjax.contact import family_spec
from wfjax.program.laws import common_extent

CASES = {
    "new": ([wf.Flat.new(d) for d in (0.4e-3, 0.75e-3, 1.25e-3, 1.75e-3)],
            np.arange(20.0, 301.0, 40.0)),
    "rounded": ([wf.Flat.rounded_relative(d, lam) for d, lam in
                 ((0.75e-3, 1.76), (1.5e-3, 1.76), (0.9e-3, 1.96), (1.2e-3, 2.3))],
                np.array([40.0, 100.0, 160.0, 220.0])),
}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--kind", choices=sorted(CASES), default="new")
    p.add_argument("--length-step", type=float, default=family_spec.LENGTH_FACTOR_STEP,
                   help="length-factor lattice step of the family (rounded flats)")
    a = p.parse_args()
    family_spec.LENGTH_FACTOR_STEP = a.length_step
    flats, speeds_kmh = CASES[a.kind]
    flats = common_extent(flats)
    out = {}
    for mode in ("parametric", "table"):
        t0 = time.perf_counter()
        out[mode] = wf.sweep(flats, speeds_kmh / 3.6, 4, contact="3d",
                             track=wf.Track.comparison(),
                             config=wf.SimConfig(contact_mode_3d=mode), progress=False)
        print(f"{mode}: {time.perf_counter() - t0:.1f} s")
    rel = np.abs(out["parametric"].max_force / out["table"].max_force - 1)
    for f, r in zip(out["table"].flats, rel.max(axis=(1, 2)), strict=True):
        print(f"| {f} | {r * 100:.3f} % |")
    same = np.array_equal(out["parametric"].loss_of_contact, out["table"].loss_of_contact)
    print(f"worst {rel.max() * 100:.3f} %; loss-of-contact flags identical: {same}")


if __name__ == "__main__":
    main()

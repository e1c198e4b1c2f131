"""The figures of docs/real_track.md, "One-sided supports": a hanging sleeper (index 35, at
x = 0.65 m) under a 0.9 mm x 100 mm rounded flat at 100 km/h (Hertz, profile input).

Prints (1) the loop against the Newmark integration of the full FE track with Kelvin-Voigt
one-sided supports (tests/fe_reference.py) for gaps of 0.05 and 0.3 mm, impact at 0.62 m;
(2) the peak over the supported track, the linear void and a 0.3 mm gap; (3) a vanishing gap
(1 nm, impact at 0.1 m) against the supported track at three time steps.

Run: ``python benchmarks/one_sided_supports.py`` (a few minutes: the Newmark runs).
"""

import dataclasses
import sys
from pathlib import Path

import numpy as np

import wfjax as wf
from wfjax.model import supports
from wfjax.scenario.windows import RUN_IN_TIME

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from fe_reference import newmark_wheels  # noqa: E402

FLAT, V = wf.Flat.rounded(0.9e-3, 0.1), 100 / 3.6


def run(track, impact, config=None):
    return wf.simulate(FLAT, V, contact="hertz-profile", impact_position=impact, track=track,
                       config=config or wf.SimConfig())


def main():
    for gap in (0.05e-3, 0.3e-3):
        track = supports.hanging_sleeper(wf.Track(n_bays=70), 35, gap)
        res = run(track, 0.62)
        x, out = np.asarray(res.x), []
        f = newmark_wheels(FLAT, V, x[0], x[0] - float(res.s[0]), [0.0], float(res.time_step),
                           x.size, track=track, supports_out=out)
        a = np.asarray(res.t) >= 0.5 * RUN_IN_TIME
        fm, fn = np.asarray(res.force)[a], f[a, 0]
        sm, sn = np.asarray(res.support_force)[a, 0], out[0][a, 0]
        print(f"gap {gap * 1e3:g} mm (loop / Newmark): max {fm.max() / 1e3:.2f} / "
              f"{fn.max() / 1e3:.2f} kN, min {fm.min() / 1e3:.2f} / {fn.min() / 1e3:.2f} kN, "
              f"ballast peak {sm.max() / 1e3:.2f} / {sn.max() / 1e3:.2f} kN, open steps "
              f"{np.sum(sm == 0)} / {np.sum(sn == 0)}")
    for name, track in (("supported", wf.Track(n_bays=70, ends="absorbing")),
                        ("linear void", supports.void_sleeper(wf.Track(n_bays=70), 35)),
                        ("0.3 mm gap", supports.hanging_sleeper(wf.Track(n_bays=70), 35, 3e-4))):
        print(f"{name}: peak {float(run(track, 0.62).max_force) / 1e3:.1f} kN")
    tiny = supports.hanging_sleeper(wf.Track(n_bays=70), 35, 1e-9)
    for dt in (2.5e-5, 1.25e-5, 6.25e-6):
        config = dataclasses.replace(wf.SimConfig(), time_step=dt)
        base, hang = run(wf.Track(n_bays=70, ends="absorbing"), 0.1, config), run(tiny, 0.1, config)
        diff = np.max(np.abs(np.asarray(hang.force) - np.asarray(base.force)))
        lift = int(np.sum(np.asarray(hang.support_force) == 0))
        print(f"1 nm gap, dt {dt * 1e6:g} us: peak {float(hang.max_force) / 1e3:.2f} against "
              f"{float(base.max_force) / 1e3:.2f} kN supported; history differs by up to "
              f"{diff / 1e3:.2f} kN; lifted off for {lift} steps")


if __name__ == "__main__":
    main()

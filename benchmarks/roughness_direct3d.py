"""Error of the contact-filtered tabulated 3D law against the direct 3D mode under roughness.

The tabulated 3D law (like the Hertz laws) sees rail roughness through the contact filter
over the static Hertz contact length; the direct mode (``contact_mode_3d="direct"``) takes it
off the gap of every Kalker element row while the flat is within the contact grid's reach.
Case: rounded flat 0.9 mm x 100 mm, 100 km/h, impact above a sleeper, the comparison track
(R_R = 0.45 m); rail roughness: one ISO 3095-limit realisation (seed 0) and 3 um sinusoids of
30 and 80 mm wavelength. Printed per roughness: max force of both modes and, inside the
direct window (|s| < s_max), the largest difference of the roughness-induced force change
(rough minus smooth run of the same mode) relative to the direct mode's largest change.

Run: ``python benchmarks/roughness_direct3d.py`` (several minutes on 2 cores: every direct
run solves Kalker at each Newton iterate near the flat).
"""

from __future__ import annotations

import os
import sys

import numpy as np

import wfjax as wf
from wfjax.scenario import roughness as R


def main() -> None:
    flat, v, track = wf.Flat.rounded(depth=0.9e-3, length=0.1), 100 / 3.6, wf.Track.comparison()
    x = np.arange(-3.0, 3.0, 2.5e-4)
    cases = {
        "ISO 3095 limit, seed 0": R.generate(R.ISO3095_LIMIT, 0, 6.0, x_start=-3.0),
        "3 um sine, 30 mm": R.Roughness(-3.0, 2.5e-4, 3e-6 * np.sin(2 * np.pi * x / 0.03)),
        "3 um sine, 80 mm": R.Roughness(-3.0, 2.5e-4, 3e-6 * np.sin(2 * np.pi * x / 0.08)),
        "3 um sine, 200 mm": R.Roughness(-3.0, 2.5e-4, 3e-6 * np.sin(2 * np.pi * x / 0.2)),
    }
    only = sys.argv[1:]
    cases = {k: r for k, r in cases.items() if not only or any(o in k for o in only)}
    modes = {"table": wf.SimConfig(), "direct": wf.SimConfig(contact_mode_3d="direct")}
    law = wf.contact.laws.prepare("3d", flat, wf.Wheel(), track, wf.Material(), modes["direct"])
    s_max = float(law.layout.s_max)

    def run(mode, rough):
        return wf.simulate(flat, v, contact="3d", track=track, config=modes[mode],
                           roughness=rough)

    smooth = {m: run(m, None) for m in modes}
    window = np.abs(np.asarray(smooth["direct"].s)) < s_max
    print("| roughness | max force table [kN] | max force direct [kN] | difference | "
          "change of max force table / direct [kN] | force change in the window: rms of "
          "the difference / rms direct |")
    print("| --- | --- | --- | --- | --- | --- |")
    base_t, base_d = (float(smooth[m].max_force) / 1e3 for m in modes)
    print(f"| none | {base_t:.2f} | {base_d:.2f} | {100 * (base_t / base_d - 1):+.2f} % | - | "
          "- |")
    for label, rough in cases.items():
        res = {m: run(m, rough) for m in modes}
        dt, dd = (np.asarray(res[m].force) - np.asarray(smooth[m].force) for m in modes)
        ft, fd = (float(res[m].max_force) / 1e3 for m in modes)
        rms = np.sqrt(np.mean((dt - dd)[window] ** 2) / np.mean(dd[window] ** 2))
        print(f"| {label} | {ft:.2f} | {fd:.2f} | {100 * (ft / fd - 1):+.2f} % | "
              f"{ft - base_t:+.2f} / {fd - base_d:+.2f} | {100 * rms:.0f} % (rms direct "
              f"{np.sqrt(np.mean(dd[window] ** 2)) / 1e3:.2f} kN) |")
    print(f"load average {' '.join(f'{a:.1f}' for a in os.getloadavg())}")


if __name__ == "__main__":
    main()

"""The bogie against the reference: axle-box acceleration peaks and wheel max forces of the
new and old defaults (issue 33: the accuracy table checks one wheel; the baselines showed the
bogie's axle-acceleration history moving by 10 % of its peak with the new defaults).

Reference as in ``accuracy_table.py`` (26 el./bay, 20 kHz, 6.25 us / 0.25 mm, 70 bays); a
bogie (2.5 m), rounded flat 0.9 mm x 100 mm on the leading wheel, Hertz-trajectory, impact at
0.2 m, 60 / 100 / 140 km/h. Prints the largest relative errors over speeds and wheels, and
the peaks [m/s^2].

Run: ``python benchmarks/bogie_accuracy.py``.
"""

import warnings

import numpy as np

import wfjax as wf

warnings.simplefilter("ignore")  # the reference is finer than the guards need
flat = wf.Flat.rounded(0.9e-3, 0.1)
sets = {"reference": (wf.Track(elements_per_bay=26, n_bays=70),
                      wf.SimConfig(track_max_frequency=20e3, max_time_step=6.25e-6,
                                   max_travel_step=0.25e-3)),
        "new default": (wf.Track(), wf.SimConfig()),
        "old default": (wf.Track(elements_per_bay=8, n_bays=70),
                        wf.SimConfig(track_max_frequency=10e3))}
out = {}
for name, (tr, cfg) in sets.items():
    for v in (60, 100, 140):
        r = wf.simulate(flat, v / 3.6, contact="hertz-trajectory", impact_position=0.2,
                        vehicle=wf.Vehicle.bogie(), track=tr, config=cfg)
        out[(name, v)] = (np.asarray(r.wheel_axle_acc_peak), np.asarray(r.wheel_max_force))
for name in ("new default", "old default"):
    ea, ef = (max(np.max(np.abs(out[(name, v)][i] / out[("reference", v)][i] - 1))
                  for v in (60, 100, 140)) for i in (0, 1))
    print(f"{name}: axle-acceleration peak {100 * ea:.2f} %, wheel max force {100 * ef:.2f} %")
for v in (60, 100, 140):
    print(v, {n: np.round(out[(n, v)][0], 1).tolist() for n in sets})

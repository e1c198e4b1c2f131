"""Where the default sweep's time goes: the same sweep (``_timing.FLATS``, 29 speeds, 10
positions, 3D, the default track) in one process, caches filled, interleaved rounds.

Both on the tracks the recorded figures ran (``_tracks.RECORDED``: 24 bays, absorbing ends;
``Track()`` is the 4-bay least track since 2026-12-06).

- ``--cutoffs``: the recorded default track at several mode cut-offs (``allow_inaccurate`` below the
  guards' bound): time against mode count, whose fit gives the part that does not depend on
  the modes and the cost per mode (benchmarks/README.md, issue 33);
- ``--candidates``: the new default against the old one (8 el./bay, 10 kHz, 70 bays) and the
  old mesh on 24 bays (docs/convergence.md, "The defaults of 2026-12-03").

Run: ``python benchmarks/bench_modes.py [--rounds 2] [--cutoffs] [--candidates]``.
"""

from __future__ import annotations

import argparse

import numpy as np
from _timing import interleaved_sweeps, print_ratios
from _tracks import RECORDED

import wfjax as wf
from wfjax.model import track as track_mod


def cutoffs(rounds: int) -> None:
    variants, modes, track = {}, [], wf.Track(**RECORDED)
    for f in (2e3, 5e3, 10e3, 15e3):
        n = int(track_mod.modal_model(track, max_frequency=f).poles.shape[0])
        modes.append(n)
        variants[f"{f / 1e3:g} kHz ({n} modes)"] = {
            "track": track,
            "config": wf.SimConfig(track_max_frequency=f, allow_inaccurate=True)}
    times = interleaved_sweeps(variants, rounds)
    print_ratios(times, list(variants)[-1])
    slope, fixed = np.polyfit(modes, [np.median(t) for t in times.values()], 1)
    print(f"\nfit: {fixed:.2f} s independent of the modes + {slope * 1e3:.1f} ms per mode")


def candidates(rounds: int) -> None:
    variants = {"default (26 el., 15 kHz, 24 bays)": {"track": wf.Track(**RECORDED)},
                "old default (8 el., 10 kHz, 70 bays)": {
                    "track": wf.Track(elements_per_bay=8, n_bays=70, ends="absorbing"),
                    "config": wf.SimConfig(track_max_frequency=10e3)},
                "8 el., 10 kHz, 24 bays": {"track": wf.Track(elements_per_bay=8, **RECORDED),
                                           "config": wf.SimConfig(track_max_frequency=10e3)}}
    print_ratios(interleaved_sweeps(variants, rounds), "old default (8 el., 10 kHz, 70 bays)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--cutoffs", action="store_true")
    ap.add_argument("--candidates", action="store_true")
    a = ap.parse_args()
    if a.cutoffs or not a.candidates:
        cutoffs(a.rounds)
    if a.candidates or not a.cutoffs:
        candidates(a.rounds)


if __name__ == "__main__":
    main()

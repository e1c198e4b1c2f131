"""Interleaved warm timings of the default sweep's variants (shared by the benchmarks)."""

from __future__ import annotations

import statistics
import time

import numpy as np

import wfjax as wf

FLATS = [wf.Flat.rounded(0.9e-3, 0.1), wf.Flat.new(0.9e-3)]
SPEEDS = np.arange(20.0, 300.1, 10.0) / 3.6


def interleaved_sweeps(variants: dict[str, dict], repeats: int) -> dict[str, list[float]]:
    """Wall times [s] of the default sweep (``FLATS``, ``SPEEDS``, 10 positions) with each
    variant's keyword arguments: all compiled first, then timed ``repeats`` times in turn
    (the machine is shared: interleaving spreads its load over the variants)."""
    times = {k: [] for k in variants}
    for kw in variants.values():
        wf.sweep(FLATS, SPEEDS, 10, progress=False, **kw)
    for _ in range(repeats):
        for name, kw in variants.items():
            t0 = time.perf_counter()
            wf.sweep(FLATS, SPEEDS, 10, progress=False, **kw)
            times[name].append(time.perf_counter() - t0)
    return times


def print_ratios(times: dict[str, list[float]], base: str, label: str = "variant") -> None:
    """A Markdown table of the times, their medians and the medians' ratio to ``base``."""
    ref = statistics.median(times[base])
    print(f"| {label} | warm times [s] | median [s] | / {base} |")
    print("| --- | --- | --- | --- |")
    for name, t in times.items():
        med = statistics.median(t)
        print(f"| {name} | {', '.join(f'{x:.2f}' for x in t)} | {med:.2f} | {med / ref:.2f} |")

"""Track and wheel benchmark: modal model build / cached load, moving Green's functions, and
the mesh convergence study behind the default ``Track.elements_per_bay``.

Run: ``python benchmarks/bench_track.py`` (about 1-2 minutes on 2 cores). Prints Markdown.
"""

from __future__ import annotations

import tempfile
import time

import numpy as np

import wfjax
from wfjax.model import fe as fe_mod
from wfjax.model import greens as greens_mod
from wfjax.model import track as T
from wfjax.model import wheel as W


def timed(fn, *args, **kwargs):
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


def _peak(f, h):
    i = np.argmax(np.abs(h))
    return f[i]


def timings(epb: int) -> None:
    tr = wfjax.Track(elements_per_bay=epb)
    with tempfile.TemporaryDirectory() as cache:
        model, t_cold = timed(T.modal_model, tr, cache_dir=cache)
        _, t_load = timed(T.modal_model, tr, cache_dir=cache)
        _, t_mg1 = timed(greens_mod.moving_greens, tr, 100 / 3.6, model=model)
        _, t_mg2 = timed(greens_mod.moving_greens, tr, 150 / 3.6, model=model)
    n_dof = fe_mod.assemble(tr).stiffness.shape[0]
    print(f"| {epb} | {n_dof} | {model.poles.shape[0]} | {t_cold:.1f} | {t_load:.3f} | "
          f"{t_mg1:.1f} | {t_mg2:.1f} |")


def _band_levels(f, h, edges):
    """Energy-averaged level [dB re 1 m/N] of |h|^2 in each band (log-spaced f)."""
    return np.array([10 * np.log10(np.mean(np.abs(h[(f >= a) & (f < b)]) ** 2))
                     for a, b in zip(edges[:-1], edges[1:], strict=True)])


def convergence() -> None:
    f = np.geomspace(20, 8000, 1200)
    edges = 1000 * 2.0 ** (np.arange(-16, 10) / 3)  # third-octave band edges 20 Hz .. 8 kHz
    edges = edges[(edges >= 20) & (edges <= 8000)]
    f_pp = np.arange(900.0, 980.0, 0.5)
    lo = edges[1:] <= 3000
    ref = {x: _band_levels(f, T.receptance(wfjax.Track(elements_per_bay=32), f, x), edges)
           for x in (0.0, 0.325)}
    for epb in (2, 4, 8, 16, 32):
        tr = wfjax.Track(elements_per_bay=epb)
        w0 = T.static_deflection(tr, 118e3, 0.0) * 1e3
        wm = T.static_deflection(tr, 118e3, 0.325) * 1e3
        pp = _peak(f_pp, T.receptance(tr, f_pp, 0.325))
        d = np.max([np.abs(_band_levels(f, T.receptance(tr, f, x), edges) - ref[x])
                    for x in ref], axis=0)
        print(f"| {epb} | {w0:.4f} | {wm:.4f} | {pp:.1f} | {d[lo].max():.2f} dB | "
              f"{d[~lo].max():.2f} dB |")


def main(only_convergence: bool = False) -> None:
    print("Modal model and moving Green's functions (27 excitation positions across one bay, "
          "0.1 s, dt = 25 us):\n")
    print("| el./bay | DOFs | modes <= 20 kHz | cold build [s] | cached load [s] | "
          "moving g, first speed (incl. jit) [s] | moving g, next speed [s] |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for epb in () if only_convergence else (8, 16):
        timings(epb)
    m, t_wheel = timed(W.modal_model, wfjax.Wheel())
    print(f"\nWheel modal model: {t_wheel * 1e3:.1f} ms; poles "
          + ", ".join(f"{abs(p) / 2 / np.pi:.1f} Hz (zeta {-p.real / abs(p):.2f})"
                      for p in np.asarray(m.poles)))
    print("\nMesh convergence (receptance columns: largest difference of third-octave band "
          "levels from 32 el./bay, above a sleeper and at midspan):\n")
    print("| el./bay | static 118 kN, sleeper [mm] | midspan [mm] | pinned-pinned [Hz] | "
          "third-octave level diff 20 Hz-3 kHz | 3-8 kHz |")
    print("| --- | --- | --- | --- | --- | --- |")
    convergence()


if __name__ == "__main__":
    import sys

    main(only_convergence="--convergence-only" in sys.argv)

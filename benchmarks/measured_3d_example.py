"""Generate ``wfjax/examples/measured_sections.csv``: a synthetic gauge measurement of a wheel
with a flat, seven lateral lines, one CSV, written as a gauge might (Latin-1 header, decimal
commas, ``;`` separators). Nothing in it is measured; docs/measured_flats.md describes it.

Construction (R = 0.45 m, 1 mm spacing, 2827 samples = one circumference):

* lines at y = -20, -13, -6, 0, 6, 13, 20 mm (the measured band, 40 mm);
* the flat at 1000 mm: a rounded V along the circumference, v(x) = (sqrt(a^2 + h^2) -
  sqrt(a^2 + x^2)) / (sqrt(a^2 + h^2) - a) clipped to [0, 1], half length h = 25 mm, tip
  rounding a = 6 mm, scaled per line by the depths 0.05, 0.30, 0.52, 0.60, 0.55, 0.43,
  0.27 mm (deepest near the centre line, falling asymmetrically to the band's edges);
* out-of-roundness: the same Gaussian random profile on every line (numpy seed 35, white
  noise smoothed by a 15 mm Hann window, periodic, 15 um RMS) plus an independent 2 um RMS
  part per line (the gauge's noise), and a 10 um once-per-revolution eccentricity;
* deviation positive outward (the flat is a dip), rounded to 0.1 um.

Run: ``python benchmarks/measured_3d_example.py`` (rewrites the file; deterministic).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parents[1] / "wfjax" / "examples" / "measured_sections.csv"
LINES_MM = np.array([-20.0, -13.0, -6.0, 0.0, 6.0, 13.0, 20.0])
DEPTHS_MM = np.array([0.05, 0.30, 0.52, 0.60, 0.55, 0.43, 0.27])
RADIUS = 0.45
CENTRE_MM, HALF_MM, TIP_MM = 1000.0, 25.0, 6.0


def shape(x_mm):
    """The rounded V [0, 1] along the circumference (module docstring)."""
    top = math.hypot(TIP_MM, HALF_MM)
    v = (top - np.hypot(TIP_MM, x_mm - CENTRE_MM)) / (top - TIP_MM)
    return np.clip(v, 0.0, 1.0)


def periodic_noise(rng, n, rms_um, window_mm):
    """Periodic Gaussian noise [um], white noise circularly smoothed by a Hann window."""
    w = np.hanning(int(window_mm) + 2)[1:-1]
    kernel = np.zeros(n)
    kernel[: w.size] = w
    noise = np.real(np.fft.ifft(np.fft.fft(rng.standard_normal(n)) * np.fft.fft(kernel)))
    return noise / noise.std() * rms_um


def records():
    """(position [n] mm, deviation [7, n] um) of the synthetic measurement."""
    n = int(round(2 * math.pi * RADIUS * 1e3))
    x = np.arange(n, dtype=float)
    rng = np.random.default_rng(35)
    common = periodic_noise(rng, n, 15.0, 15) + 10.0 * np.cos(2 * np.pi * x / n)
    dev = np.empty((LINES_MM.size, n))
    for j, depth in enumerate(DEPTHS_MM):
        dev[j] = common + periodic_noise(rng, n, 2.0, 5) - 1e3 * depth * shape(x)
    return x, np.round(dev, 1)


def main():
    x, dev = records()
    head = ("Radprofil-Messung (synthetisch), Rad Nr. 35, Messlinien quer zur Lauffläche\n"
            "Abweichung in µm, Position in mm, Lateralpositionen mm: "
            + " ".join(f"{v:g}" for v in LINES_MM) + "\n")
    cols = "Position mm;" + ";".join(f"Linie {j + 1}" for j in range(LINES_MM.size)) + "\n"
    rows = [";".join([f"{xi:g}"] + [f"{v:.1f}" for v in d]).replace(".", ",")
            for xi, d in zip(x, dev.T, strict=True)]
    OUT.write_bytes((head + cols + "\n".join(rows) + "\n").encode("latin-1"))
    print(f"wrote {OUT} ({OUT.stat().st_size} bytes)")


if __name__ == "__main__":
    main()

"""The track model's truncated modes: the static correction alone against the damper
augmentation (issue 33, docs/convergence.md "Truncated modes").

The transfer receptance of the rail's displacement and shear (force at 0.3 m, sensors at
1.0 and -0.45 m, 20 Hz - 2 kHz, 40 log-spaced points) of the modal model
(``wfjax.scenario.sensors.transfer_receptance``) against a direct sparse frequency-domain
solve of the same FE mesh (no modes), on the default 24-bay track, at several cut-offs and
meshes, with the pseudo-modes of ``wfjax.model.track._damper_augmentation`` and without them
(the function replaced by one that adds none: the model before 2026-12-05).

Run: ``python benchmarks/truncation.py``; writes ``benchmarks/results/truncation.json`` and
prints a Markdown table (largest relative error over frequency and both sensors).
"""

from __future__ import annotations

import json
import pathlib
from unittest import mock

import numpy as np
import scipy.sparse.linalg
from _tracks import RECORDED  # benchmarks/, the script's folder

import wfjax as wf
from wfjax.model import beam as beam_mod
from wfjax.model import fe as fe_mod
from wfjax.model import track as track_mod
from wfjax.scenario import sensors as sensor_mod

FREQS = np.geomspace(20.0, 2000.0, 40)
X_FORCE, X_SENSORS = 0.3, np.array([1.0, -0.45])
CASES = [(26, 5e3), (26, 10e3), (26, 15e3), (26, 20e3), (26, 30e3), (8, 10e3), (8, 20e3)]


def direct(track, quantity: str) -> np.ndarray:
    """[n_f, n_s] receptance of the FE mesh by a sparse solve per frequency (m/N or N/N)."""
    fe = fe_mod.assemble(track)
    b = fe_mod.load_vector(fe, X_FORCE).toarray()[:, 0].astype(complex)
    if quantity == "rail_disp":
        obs = fe_mod.load_vector(fe, X_SENSORS).toarray()
    else:  # the element's end shear: the first row of its stiffness times its DOFs
        ke, _, _ = beam_mod.element_matrices(track.bending_stiffness, track.shear_stiffness,
                                           track.rail_mass, track.rail_rotary_inertia,
                                           fe.element_length)
        obs = np.zeros((b.size, X_SENSORS.size))
        for i, x in enumerate(X_SENSORS):
            e = int(np.floor((x - fe.node_x[0]) / fe.element_length))
            obs[2 * e - 2:2 * e + 2, i] = -ke[0]
    out = np.empty((FREQS.size, X_SENSORS.size), complex)
    for i, f in enumerate(FREQS):
        w = 2 * np.pi * f
        d = (fe.stiffness - w**2 * fe.mass + 1j * w * fe.damping).tocsc()
        out[i] = obs.T @ scipy.sparse.linalg.spsolve(d, b)
    return out


def error(track, max_frequency: float, quantity: str, ref: np.ndarray) -> tuple[int, float]:
    """(modes, largest |H - H_ref| / |H_ref| [%]) of the modal model."""
    model = track_mod.modal_model(track, max_frequency=max_frequency, use_cache=False)
    h = np.stack([sensor_mod.transfer_receptance(track, model, FREQS, X_FORCE, x, quantity)
                  for x in X_SENSORS], axis=1)
    return int(np.asarray(model.poles).size), 100 * float(np.max(np.abs(h - ref) / np.abs(ref)))


def none_added(vec, w2, keep, dampers):
    """No pseudo-modes: the static correction alone."""
    return vec[:, :0], w2[:0]


def main() -> None:
    rows = []
    for elements, f_max in CASES:
        track = wf.Track(elements_per_bay=elements, **RECORDED)
        for quantity in ("shear", "rail_disp"):
            ref = direct(track, quantity)
            n_aug, e_aug = error(track, f_max, quantity, ref)
            with mock.patch.object(track_mod, "_damper_augmentation", none_added):
                n_old, e_old = error(track, f_max, quantity, ref)
            rows.append({"elements_per_bay": elements, "max_frequency_Hz": f_max,
                         "quantity": quantity, "modes_static": n_old, "error_static_pct": e_old,
                         "modes_augmented": n_aug, "error_augmented_pct": e_aug})
            print(rows[-1], flush=True)
    path = pathlib.Path(__file__).parent / "results" / "truncation.json"
    path.write_text(json.dumps(rows, indent=1))
    print("| el./bay | cut-off | quantity | static correction: modes, error % | "
          "augmented: modes, error % |\n|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['elements_per_bay']} | {r['max_frequency_Hz'] / 1e3:g} kHz | "
              f"{r['quantity']} | {r['modes_static']}, {r['error_static_pct']:.2f} | "
              f"{r['modes_augmented']}, {r['error_augmented_pct']:.3f} |")


if __name__ == "__main__":
    main()

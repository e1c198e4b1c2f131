"""Baselines of issue 30 ("one scenario, one compiled program"): results of the code before
the restructuring, which the restructured code must reproduce (``tests/test_baselines.py``).

Each case is a function returning ``{name: array}`` through the public API only (the API the
restructuring keeps). ``python tests/baselines.py`` writes ``tests/data/issue30_baselines.npz``
and ``tests/data/single_wheel_reference.npz``, each case from an empty cache (``WFJAX_CACHE_DIR``
set to a fresh directory, as each test does), with the commit it ran on.

Tolerance of the comparison: 1e-12 relative on maxima, plus 1e-12 P absolute on minima (which
sit near zero where contact is lost); histories are compared with the same bound on their
largest magnitude.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

PATH = Path(__file__).parent / "data" / "issue30_baselines.npz"
ROUNDED_DEPTH, ROUNDED_LENGTH = 0.9e-3, 0.1  # m
SPEED = 100 / 3.6  # m/s


def _wf():
    import jax

    jax.config.update("jax_enable_x64", True)
    import wfjax

    return wfjax


def _f64(wf):
    """The float64 loop: the baselines hold to 1e-12, which float32 (the forward default since
    2026-12-04, ``SimConfig.precision="auto"``) cannot; tests/test_precision.py bounds it."""
    return wf.SimConfig(precision="float64")


def default_sweep() -> dict:
    """The README's main job: ``wfjax sweep`` (Fig. 7 case, 3D tables)."""
    wf = _wf()
    flats = [wf.Flat.rounded(ROUNDED_DEPTH, ROUNDED_LENGTH), wf.Flat.new(ROUNDED_DEPTH)]
    speeds = np.arange(20.0, 300.0 + 1e-9, 10.0) / 3.6
    res = wf.sweep(flats, speeds, 10, contact="3d", progress=False, config=_f64(wf))
    return {"max_force": np.asarray(res.max_force), "min_force": np.asarray(res.min_force)}


# the single-wheel cases' track: 24 bays, which hold the run and its sensors, so the runs
# with and without sensors in the tests share it (the default track, 4 bays with end
# networks, is lengthened to what each run's sensors need)
SINGLE_BAYS = 24


def single_wheel(contact: str) -> dict:
    """The single-wheel fixture's case (``tests/data/single_wheel_reference.npz``)."""
    wf = _wf()
    res = wf.simulate(wf.Flat.rounded(ROUNDED_DEPTH, ROUNDED_LENGTH), SPEED, contact=contact,
                      impact_position=0.1, track=wf.Track(n_bays=SINGLE_BAYS),
                      sensors=[0.2, 0.5],
                      sensor_quantities=("shear", "seat_force"), config=_f64(wf))
    out = {k: np.asarray(getattr(res, k)) for k in ("force", "rail_disp", "wheel_disp",
                                                    "approach")}
    out |= {f"sensors/{q}": np.asarray(v) for q, v in res.sensors.items()}
    return out


def bogie() -> dict:
    """Two wheels on one rail, the leading one with the flat (Hertz trajectory)."""
    wf = _wf()
    from wfjax.model.vehicle import Vehicle

    res = wf.simulate(wf.Flat.rounded(ROUNDED_DEPTH, ROUNDED_LENGTH), SPEED,
                      contact="hertz-trajectory", impact_position=0.2, vehicle=Vehicle.bogie(),
                      config=_f64(wf))
    return {"wheel_force": np.asarray(res.wheel_force), "force": np.asarray(res.force),
            "axle_acc": np.asarray(res.wheel_axle_acc)}


def rough_void() -> dict:
    """A rough rail over a void sleeper (the middle one, x = 0.65 m, fully void) and over a
    hanging one (gap)."""
    wf = _wf()
    from wfjax.model import supports
    from wfjax.scenario import roughness

    track = wf.Track(n_bays=24)  # the per-sleeper supports' length (and absorbing ends)
    rough = roughness.generate(roughness.ISO3095_LIMIT, 0, 6.0, x_start=-3.0)
    flat = wf.Flat.rounded(ROUNDED_DEPTH, ROUNDED_LENGTH)
    void = wf.simulate(flat, SPEED, contact="hertz-trajectory", impact_position=0.65,
                       track=supports.void_sleeper(track, track.n_bays // 2), roughness=rough,
                       config=_f64(wf))
    hang = wf.simulate(flat, SPEED, contact="2d", impact_position=0.62,
                       track=supports.hanging_sleeper(track, track.n_bays // 2, 0.3e-3),
                       roughness=rough, config=_f64(wf))
    return {"void/force": np.asarray(void.force), "void/rail_disp": np.asarray(void.rail_disp),
            "hanging/force": np.asarray(hang.force),
            "hanging/support_force": np.asarray(hang.support_force)}


def detector() -> dict:
    """The detector's readings over a speed sweep and one simulation's load histories."""
    wf = _wf()
    from wfjax.scenario.sensors import Detector

    flat = wf.Flat.rounded(ROUNDED_DEPTH, ROUNDED_LENGTH)
    det = Detector(n_bays=3)
    res = wf.simulate(flat, SPEED, contact="hertz-trajectory", impact_position=0.3,
                      detector=det, config=_f64(wf))
    sw = wf.sweep([flat], np.array([40.0, 120.0]) / 3.6, 3, contact="hertz-trajectory",
                  detector=det, progress=False, config=_f64(wf))
    return {"sim/detector_peak": np.asarray(res.detector_peak),
            "sim/detector_load": np.asarray(res.detector_load),
            "sweep/detector_peak": np.asarray(sw.detector_peak),
            "sweep/max_force": np.asarray(sw.max_force)}


def fit3d_gradient() -> dict:
    """The first gradient of a 3D max-force fit (parametric family, hand-written adjoint)."""
    wf = _wf()
    import jax
    import jax.numpy as jnp

    from wfjax import fit

    speeds = np.array([60.0, 100.0, 140.0]) / 3.6
    initial = wf.Flat.rounded(1.1e-3, 0.12)
    par = fit.parametrisation_for(initial)
    model = fit.max_force_model(speeds, par.to_flat(jnp.asarray(par.from_flat(initial))),
                                contact="3d", impact_positions=2, adjoint=True,
                                extent_bound=par.extent_bound)
    measured = jnp.asarray([150e3, 200e3, 230e3])

    def loss(theta):
        return jnp.mean(((model(par.to_flat(theta)) - measured) / 2e5) ** 2)

    theta0 = jnp.asarray(par.from_flat(initial))
    value, grad = jax.value_and_grad(loss)(theta0)
    return {"loss": np.asarray(value), "grad": np.asarray(grad)}


CASES = {
    "default_sweep": default_sweep,
    **{f"single/{c}": (lambda c=c: single_wheel(c))
       for c in ("hertz-profile", "hertz-trajectory", "2d", "3d")},
    "bogie": bogie,
    "rough_void": rough_void,
    "detector": detector,
    "fit3d": fit3d_gradient,
}


SINGLE_WHEEL_PATH = Path(__file__).parent / "data" / "single_wheel_reference.npz"
SINGLE_WHEEL_CONTACTS = ("hertz-profile", "hertz-trajectory", "2d", "3d")


def _empty_cache() -> None:
    """Point the cache at a new empty directory: every case builds its own 3D tables, as each
    test does (a table built beside other flats' shares their window sizes and differs from
    one built alone by up to the float32 solves' tolerance, ~3e-7 of its largest force:
    ``wfjax.contact.tables.build_tables_3d``)."""
    os.environ["WFJAX_CACHE_DIR"] = tempfile.mkdtemp(prefix="wfjax-baseline-")


def write_single_wheel(commit: str) -> None:
    """Write :data:`SINGLE_WHEEL_PATH`: every contact model's histories of
    :func:`single_wheel`, and the Hertz-trajectory run's sensors."""
    out = {"commit": np.asarray(commit)}
    for contact in SINGLE_WHEEL_CONTACTS:
        _empty_cache()
        res = single_wheel(contact)
        out |= {f"{contact}/{k}": v for k, v in res.items() if not k.startswith("sensors/")}
        if contact == "hertz-trajectory":
            out |= {k: v for k, v in res.items() if k.startswith("sensors/")}
    np.savez_compressed(SINGLE_WHEEL_PATH, **out)
    print(f"wrote {SINGLE_WHEEL_PATH} ({len(out)} arrays) at {commit}")


def main() -> None:
    """Write :data:`PATH` and :data:`SINGLE_WHEEL_PATH`, each case from an empty cache."""
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                            cwd=Path(__file__).parent).stdout.strip()
    out = {"commit": np.asarray(commit)}
    for name, fn in CASES.items():
        print(name, file=sys.stderr, flush=True)
        _empty_cache()
        out |= {f"{name}::{k}": v for k, v in fn().items()}
    np.savez_compressed(PATH, **out)
    print(f"wrote {PATH} ({len(out)} arrays) at {commit}")
    write_single_wheel(commit)


if __name__ == "__main__":
    main()

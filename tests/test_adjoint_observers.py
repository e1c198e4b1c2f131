"""The adjoint's instrument observers (issue 30, item 2): sensors and the wheel impact load
detector through wfjax.loop.adjoint give run_scan's outputs bit for bit and plain autodiff's
gradients, and central differences agree.

Short runs as tests/test_adjoint.py (400 steps of 30 us at 100 km/h, Hertz-trajectory law,
float64); the gradient is with respect to the flat's depth d. Central differences use the
step h = 2e-7 m (0.02 % of d = 0.9 mm): small enough for the 1 % tolerance, large enough
that rounding (~1e-16 relative in the losses) stays far below it.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wfjax as wf
from wfjax import fit
from wfjax.contact import laws
from wfjax.loop import adjoint as adj
from wfjax.loop.observers import DetectorReadings, OwnCompliance, Sensors
from wfjax.loop.run import run_scan
from wfjax.loop.structure import structure
from wfjax.model.vehicle import Vehicle, placement
from wfjax.scenario import sensors as sensor_mod

V, DT, N = 100 / 3.6, 3e-5, 400
IMPACT = 0.1
X0 = IMPACT - 0.2
DEPTH, LENGTH = 0.9e-3, 0.1
# central differences over +-H: the detector peak (a max over time) switches its sample
# between 3e-9 and 1e-8 m from DEPTH since the in-element correction (2026-12-03)
H = 2e-9
CONFIG = wf.SimConfig(contact_element=2e-3)
# 30 bays: the bogie's sensors (up to 2.05 m) keep their margin from the clamped ends
WHEEL, TRACK, MAT = wf.Wheel(), wf.Track(n_bays=30), wf.Material()
QUANTITIES = ("rail_disp", "rail_acc", "shear", "moment", "seat_force")


def _law(depth):
    flat = wf.Flat("rounded", depth, LENGTH, extent_bound=0.06)
    return laws.prepare("hertz-trajectory", flat, WHEEL, TRACK, MAT, CONFIG)


def _instruments(model, sensor_x, detector, history=True):
    spec = sensor_mod.sensor_spec(sensor_x, TRACK, model, QUANTITIES)
    det = sensor_mod.detector_spec(detector, TRACK, model)
    return (Sensors(spec, run_in=20, history=history), DetectorReadings(det, history=history))


def _losses(hist, peaks):
    """[2] or [3]: the sensor maxima minus the minima, the detector's attained peaks
    (``peaks``: bool mask of the finite ones) and, with histories, a weighted sum of the
    sensor histories; each scaled to O(1)."""
    scale = jnp.array([1e3, 1e-1, 1e-5, 1e-5, 1e-5])[:, None]  # m, m/s^2, N, N m, N
    extremes = jnp.sum(hist["sensor_max"] * scale) - jnp.sum(hist["sensor_min"] * scale)
    out = [extremes, jnp.sum(jnp.where(peaks, hist["detector_peak"], 0.0)) / 1e5]
    if "sensors" in hist:
        y = hist["sensors"] * scale
        out.append(jnp.sum(jnp.linspace(0.5, 1.5, y.shape[0])[:, None, None] * y))
    return jnp.stack(out)


def _check(run):
    """run(runner, depth) -> outputs: forward equal bit for bit; the jacobian of
    :func:`_losses` agrees with plain autodiff (1e-9 relative) and central differences
    (1 %)."""
    want, got = run(run_scan, DEPTH), run(adj.run_adjoint, DEPTH)
    assert want.keys() == got.keys()
    for k in want:
        np.testing.assert_array_equal(np.asarray(got[k]), np.asarray(want[k]), err_msg=k)
    peaks = np.isfinite(np.asarray(want["detector_peak"]))
    assert peaks.any()

    def losses(runner):
        return lambda d: _losses(run(runner, d), peaks)

    plain = np.asarray(jax.jit(jax.jacrev(losses(run_scan)))(DEPTH))
    ours = np.asarray(jax.jit(jax.jacrev(losses(adj.run_adjoint)))(DEPTH))
    f = jax.jit(losses(adj.run_adjoint))
    fd = (np.asarray(f(DEPTH + H)) - np.asarray(f(DEPTH - H))) / (2 * H)
    print("plain", plain, "adjoint", ours, "fd", fd)
    print("rel to plain", np.abs(ours - plain) / np.abs(plain), "rel to fd",
          np.abs(ours - fd) / np.abs(fd))
    assert np.all(np.abs(plain) > 0)
    np.testing.assert_allclose(ours, plain, rtol=1e-9)
    np.testing.assert_allclose(ours, fd, rtol=1e-2)


@pytest.fixture(scope="module")
def struct():
    return structure(Vehicle.single(), [WHEEL], TRACK, CONFIG)


@pytest.mark.slow
def test_one_wheel_sensors_and_detector(struct):
    obs = _instruments(struct.track, [0.0, 0.3], sensor_mod.Detector(n_bays=2, first_bay=-1))
    for history in (True, False):
        chosen = tuple(dataclasses.replace(o, history=history) for o in obs)

        def run(runner, depth, chosen=chosen):
            return runner(_law(depth), struct, V, DT, X0, IMPACT, N, observers=chosen)

        _check(run)

@pytest.mark.slow
def test_two_wheel_vehicle_sensors_and_detector():
    vehicle = Vehicle.bogie()
    vstruct = structure(vehicle, [WHEEL, WHEEL], TRACK, CONFIG)
    smooth = laws.prepare("hertz-trajectory", wf.Flat.none(), WHEEL, TRACK, MAT, CONFIG)
    x_imp = placement(vehicle, float(TRACK.sleeper_spacing)) + IMPACT
    offset = float(vehicle.offsets()[1])
    # a sensor near each wheel's path; bays under both wheels (the others' peaks stay -inf)
    obs = _instruments(vstruct.track, [x_imp + 0.05, x_imp + offset + 0.05],
                       sensor_mod.Detector(n_bays=5, first_bay=-2))

    def run(runner, depth):
        return runner((_law(depth), smooth), vstruct, V, DT, x_imp - 0.2, x_imp, N,
                      observers=obs)

    _check(run)


def test_non_instrument_observers_raise(struct):
    with pytest.raises(NotImplementedError, match="OwnCompliance"):
        adj.adjoint_loop(_law(DEPTH), struct, V, DT, X0, IMPACT, 50,
                         observers=(OwnCompliance(),))


@pytest.mark.slow
def test_detector_model_adjoint_option():
    """detector_model(adjoint=True): the same readings bit for bit, plain autodiff's gradient."""
    coarse = wf.SimConfig(max_travel_step=1e-3, max_time_step=5e-5)
    ref = wf.Flat("rounded", DEPTH, LENGTH, extent_bound=0.06)
    speeds = np.array([60.0, 120.0]) / 3.6
    kw = dict(impact_positions=[0.3], per_bay=True, config=coarse)
    plain = fit.detector_model(speeds, ref, **kw)
    ours = fit.detector_model(speeds, ref, adjoint=True, **kw)
    assert ours.info["adjoint"] and not plain.info["adjoint"]

    def flat(th):
        return wf.Flat("rounded", th[0], th[1], extent_bound=0.06)

    th0 = jnp.array([DEPTH, LENGTH])
    np.testing.assert_array_equal(np.asarray(jax.jit(lambda th: ours(flat(th)))(th0)),
                                  np.asarray(jax.jit(lambda th: plain(flat(th)))(th0)))

    def misfit(model):
        return lambda th: jnp.sum((model(flat(th)) / 1e5) ** 2)

    g_plain = np.asarray(jax.jit(jax.grad(misfit(plain)))(th0))
    g_ours = np.asarray(jax.jit(jax.grad(misfit(ours)))(th0))
    print("detector_model gradient: plain", g_plain, "adjoint", g_ours, "rel",
          np.abs(g_ours - g_plain) / np.abs(g_plain))
    assert np.all(np.abs(g_plain) > 0)
    np.testing.assert_allclose(g_ours, g_plain, rtol=1e-9)

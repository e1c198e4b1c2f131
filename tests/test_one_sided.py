"""Hanging sleepers over a gap that closes under load (issue 18): the one-sided ballast
against a direct non-linear static FE solve and a direct FE time integration."""

import dataclasses

import numpy as np
import pytest
import scipy.sparse.linalg
from fe_reference import newmark_wheels

import wfjax as wf
from wfjax.contact.laws import prepare
from wfjax.loop.run import run_scan
from wfjax.loop.structure import structure
from wfjax.model import beam as beam_mod
from wfjax.model import fe as fe_mod
from wfjax.model import sleepers, supports
from wfjax.model import track as track_mod
from wfjax.model.track import RESIDUAL_POINTS_PER_ELEMENT
from wfjax.model.vehicle import Vehicle
from wfjax.program.laws import vehicle_laws
from wfjax.scenario.windows import RUN_IN_TIME

F64 = wf.SimConfig(precision="float64")  # identities to rounding: the float64 loop

ROUNDED = wf.Flat.rounded(depth=0.9e-3, length=0.1)
V = 100 / 3.6
TRACK = wf.Track(n_bays=24)  # hanging sleepers: absorbing ends (Track.ends auto)
SLEEPER = TRACK.n_bays // 2  # at x = 0.65 m
# a point of the residual table (8 per element) 9/32 of a bay past that sleeper
GRID = RESIDUAL_POINTS_PER_ELEMENT * TRACK.elements_per_bay
X_BESIDE = 0.65 + round(9 / 32 * GRID) / GRID * 0.65


def _direct_static(track, x_wheel, load):
    """(rail deflection under the wheel(s) [m], sleeper displacement [m], support force [N])
    of the open FE track with the one-sided ballast: active-set Newton, exact. ``x_wheel``
    and ``load`` [N] scalars or [n_w]."""
    fe = fe_mod.assemble(track)
    k = scipy.sparse.linalg.splu(fe.stiffness.tocsc())
    idx = supports.hanging_sleepers(track)
    arrays = sleepers.support_arrays(track)
    gap, k_b = arrays["ballast_gap"][idx], arrays["ballast_stiffness"][idx]
    b = fe_mod.load_vector(fe, np.atleast_1d(x_wheel)).toarray()
    e = np.zeros((b.shape[0], idx.size))
    e[fe.n_rail_dof + idx, np.arange(idx.size)] = 1.0
    u_p, g = k.solve(b @ np.atleast_1d(load)), k.solve(e)
    f = np.zeros(idx.size)
    for _ in range(20):
        active = (e.T @ (u_p - g @ f) - gap) > 0
        f = np.linalg.solve(np.eye(idx.size) + (k_b * active)[:, None] * (e.T @ g),
                            k_b * active * (e.T @ u_p - gap))
    u = u_p - g @ f
    own = beam_mod.element_interior_compliance(  # each load's deflection inside its element
        track, track_mod.element_fraction(fe, np.atleast_1d(x_wheel)))
    rail = b.T @ u + own * np.atleast_1d(load)
    return (rail[0] if np.ndim(x_wheel) == 0 else rail), e.T @ u, f


def _static_start(track, x_wheel):
    config = wf.SimConfig()
    struct = structure(Vehicle.single(), [wf.Wheel()], track, config)
    law = prepare("hertz-profile", wf.Flat.none(), wf.Wheel(), track, wf.Material(), config)
    return run_scan(law, struct, V, 2e-5, x_wheel, x_wheel + 1.0, 2)


@pytest.mark.parametrize("gap_mm, closed", [
    (0.2, True), pytest.param(0.6, True, marks=pytest.mark.slow),
    pytest.param(5.0, False, marks=pytest.mark.slow)])  # the default run: under 10 min
def test_static_start_equals_a_direct_non_linear_static_fe_solve(gap_mm, closed):
    # two sleepers hang; the wheel on residual-grid points over and beside them
    track = supports.hanging_sleeper(TRACK, [SLEEPER, SLEEPER + 1], gap_mm * 1e-3)
    for x_wheel in (0.65, X_BESIDE, 1.3):
        hist = _static_start(track, x_wheel)
        rail, sleeper, force = _direct_static(track, x_wheel, wf.Wheel().preload)
        assert (force[0] > 0) == closed or x_wheel > 1.0
        np.testing.assert_allclose(float(hist["rail_disp"][0]), rail, rtol=1e-9)
        np.testing.assert_allclose(np.asarray(hist["sleeper_disp"][0]), sleeper, rtol=1e-9)
        np.testing.assert_allclose(np.asarray(hist["support_force"][0]), force, rtol=1e-8,
                                   atol=1e-6)


def test_bogie_static_start_over_a_hanging_sleeper_equals_the_direct_solve():
    from wfjax.model.vehicle import Vehicle

    track = supports.hanging_sleeper(TRACK, SLEEPER, 0.4e-3)
    config, vehicle = wf.SimConfig(), Vehicle.bogie()
    wheels = [wf.Wheel(preload=p) for p in (118e3, 90e3)]
    struct = structure(vehicle, wheels, track, config)
    laws = vehicle_laws("hertz-profile", vehicle.flat_list(wf.Flat.none(), lambda i: 0.45),
                           wheels, track, wf.Material(), config)
    for x0 in (0.65 + 3 * 0.65 / 32, 3.25):  # the leading, then the trailing wheel near it
        hist = run_scan(laws, struct, V, 2e-5, x0, x0 + 1.0, 2)
        rail, sleeper, force = _direct_static(track, x0 + vehicle.offsets(),
                                              np.array([118e3, 90e3]))
        assert force[0] > 0
        # 5e-4: each wheel's own residual is read between the track table's points (8 per
        # element; test_track's test_point_load_inside_an_element_is_exact)
        np.testing.assert_allclose(np.asarray(hist["rail_disp"])[0], rail, rtol=5e-4)
        np.testing.assert_allclose(np.asarray(hist["support_force"])[0], force, rtol=5e-4)


def test_a_gap_that_never_closes_is_the_void_sleeper():
    void = supports.void_sleeper(TRACK, SLEEPER)
    deep = supports.hanging_sleeper(TRACK, SLEEPER, 0.05)
    kw = dict(contact="hertz-profile", impact_position=0.1, sensors=[0.3, 0.65],
              sensor_quantities=("rail_disp", "seat_force"), detector=wf.Detector())
    a = wf.simulate(ROUNDED, V, track=void, **kw, config=F64)
    b = wf.simulate(ROUNDED, V, track=deep, **kw, config=F64)
    np.testing.assert_allclose(np.asarray(b.force), np.asarray(a.force), rtol=1e-12,
                               atol=1e-9 * float(a.max_force))
    assert np.all(np.asarray(b.support_force) == 0.0)
    pairs = [(a.detector_peak, b.detector_peak), (a.detector_load, b.detector_load)]
    pairs += [(a.sensors[q], b.sensors[q]) for q in ("rail_disp", "seat_force")]
    for ref, got in pairs:  # readings over a hanging sleeper, too
        ref = np.asarray(ref)
        np.testing.assert_allclose(np.asarray(got), ref, rtol=1e-10,
                                   atol=1e-10 * np.abs(ref).max())


def test_a_closing_gap_carries_load_only_while_closed():
    # 0.3 mm closes under the wheel over the sleeper (its void deflection: ~1.7 mm)
    track = supports.hanging_sleeper(TRACK, SLEEPER, 3e-4)
    hang = wf.simulate(ROUNDED, V, contact="hertz-profile", impact_position=0.62, track=track)
    force, disp = np.asarray(hang.support_force)[:, 0], np.asarray(hang.sleeper_disp)[:, 0]
    assert force.max() > 0.3 * wf.Wheel().preload
    open_ = disp <= 3e-4
    assert open_.any() and np.all(force[open_] == 0.0)  # open gap: no force, no tension
    assert np.all(force >= 0.0)


@pytest.mark.slow
@pytest.mark.parametrize("gap_mm", [0.05, 0.3])
def test_hanging_sleeper_agrees_with_a_direct_fe_time_integration(gap_mm):
    track = supports.hanging_sleeper(TRACK, SLEEPER, gap_mm * 1e-3)
    res = wf.simulate(ROUNDED, V, contact="hertz-profile", impact_position=0.62, track=track)
    x = np.asarray(res.x)
    out = []
    forces = newmark_wheels(ROUNDED, V, x[0], x[0] - float(res.s[0]), [0.0],
                            float(res.time_step), x.size, track=track, supports_out=out)
    after = np.asarray(res.t) >= 0.5 * RUN_IN_TIME
    fm, fn = np.asarray(res.force)[after], forces[after, 0]
    assert fn.max() == pytest.approx(fm.max(), rel=0.02)
    assert fn.min() == pytest.approx(fm.min(), abs=0.02 * fm.max())
    sm, sn = np.asarray(res.support_force)[after, 0], out[0][after, 0]
    assert sn.max() == pytest.approx(sm.max(), rel=0.03)


@pytest.mark.slow
def test_hanging_sleeper_gradient_matches_finite_differences():
    import jax

    track = supports.hanging_sleeper(TRACK, SLEEPER, 3e-4)
    config = wf.SimConfig()
    struct = structure(Vehicle.single(), [wf.Wheel()], track, config)

    def peak(depth):
        flat = dataclasses.replace(ROUNDED, depth=depth, extent_bound=0.06)
        law = prepare("hertz-profile", flat, wf.Wheel(), track, wf.Material(), config)
        hist = run_scan(law, struct, V, 2.5e-5, 0.62 - 0.1, 0.62, 1200)
        return jax.numpy.max(hist["force"])

    d0, h = 0.9e-3, 2e-6
    grad = float(jax.grad(peak)(d0))
    fd = (float(peak(d0 + h)) - float(peak(d0 - h))) / (2 * h)
    assert grad == pytest.approx(fd, rel=0.01)


@pytest.mark.parametrize("make, match", [
    (lambda: supports.hanging_sleeper(TRACK, SLEEPER, -1e-3), rf"ballast_gap\[{SLEEPER}\]"),
    (lambda: supports.hanging_sleeper(TRACK, SLEEPER, 0.2), "at most 0.05"),
    (lambda: supports.hanging_sleeper(TRACK, 99, 1e-3),
     rf"\[0, {TRACK.n_bays - 2}\]"),
    (lambda: supports.hanging_sleeper(TRACK, list(range(SLEEPER - 5, SLEEPER + 5)), 1e-3),
     "at most 8"),
    (lambda: supports.hanging_sleepers(wf.Track(ballast_gap=1e-3)), "per sleeper"),
])
def test_bad_hanging_sleepers_are_refused(make, match):
    with pytest.raises(ValueError, match=match):
        make()


@pytest.mark.parametrize("gap_mm", [0.2, 5.0])  # closed under the wheel; never closes
def test_sensor_readings_at_rest_over_hanging_sleepers_equal_the_direct_static_solve(gap_mm):
    """Rail and sleeper displacements and seat forces at the static start equal the open FE
    track's statics under the wheel load and the one-sided ballast's forces (1e-14 seen)."""
    from wfjax.loop.observers import Sensors
    from wfjax.scenario import sensors as sensor_mod

    # 30 bays: the sensors up to 2.2 m keep their 6 m from the ends of the fixed-length track
    long = wf.Track(n_bays=30)
    track = supports.hanging_sleeper(long, [long.n_bays // 2, long.n_bays // 2 + 1],
                                     gap_mm * 1e-3)
    x_wheel = X_BESIDE
    config = wf.SimConfig()
    struct = structure(Vehicle.single(), [wf.Wheel()], track, config)
    law = prepare("hertz-profile", wf.Flat.none(), wf.Wheel(), track, wf.Material(), config)
    xs = np.array([-0.3, 0.4, 0.65, 0.9, 1.3, 1.7, 2.2])
    spec = sensor_mod.sensor_spec(xs, track, struct.track)
    hist = run_scan(law, struct, V, 2e-5, x_wheel, x_wheel + 1.0, 2,
                    observers=(Sensors(spec),))
    y = np.asarray(hist["sensors"][0])
    load = float(hist["force"][0])
    fe = fe_mod.assemble(track)
    idx = supports.hanging_sleepers(track)
    force = _direct_static(track, x_wheel, load)[2]
    b = fe_mod.load_vector(fe, np.array([x_wheel])).toarray()[:, 0] * load
    b[fe.n_rail_dof + idx] -= force
    u = scipy.sparse.linalg.splu(fe.stiffness.tocsc()).solve(b)
    assert (force[0] > 0) == (gap_mm < 1)
    q = {name: i for i, name in enumerate(spec.quantities)}
    # without the support forces' direct terms: 3e-7 off (rail), 2.7e-7 P (seat)
    np.testing.assert_allclose(y[q["rail_disp"]], fe_mod.load_vector(fe, xs).T @ u, rtol=1e-10)
    nb, ne = track.n_bays, track.elements_per_bay
    nearest = np.floor(xs / 0.65 + 0.5).astype(int) + nb // 2 - 1
    sleeper_u = u[fe.n_rail_dof + nearest]
    seat = track.pad_stiffness * (u[2 * ((nearest + 1) * ne) - 2] - sleeper_u)
    np.testing.assert_allclose(y[q["sleeper_disp"]], sleeper_u, rtol=1e-10)
    np.testing.assert_allclose(y[q["seat_force"]], seat, rtol=1e-10, atol=1e-12 * load)


def test_the_adjoint_refuses_hanging_sleepers():
    from wfjax.loop import adjoint

    track = supports.hanging_sleeper(TRACK, SLEEPER, 3e-4)
    config = wf.SimConfig()
    struct = structure(Vehicle.single(), [wf.Wheel()], track, config)
    law = prepare("hertz-profile", ROUNDED, wf.Wheel(), track, wf.Material(), config)
    with pytest.raises(NotImplementedError, match="hanging sleepers"):
        adjoint.adjoint_loop(law, struct, V, 2.5e-5, 0.5, 0.62, 10)


def test_a_hanging_sleeper_in_an_absorbing_end_keeps_the_ends_grading():
    """The one-sided ballast's damping is the linear model's for the same sleeper: graded up
    inside an absorbing end (fe.end_grading), as the FE matrices grade it when it rests."""
    track = wf.Track(n_bays=8, elements_per_bay=2, ends="absorbing")
    n_sl = track.n_bays - 1
    for index in (0, 1, n_sl // 2, n_sl - 1):
        hang = supports.hanging_sleeper(track, index, 3e-4)
        model = track_mod.modal_model(hang, 5e3, use_cache=False)
        spec = supports.one_sided_spec(hang, model)
        c = fe_mod.assemble(track).damping.toarray()  # resting: pad + graded ballast
        pad_dof = fe_mod.assemble(track).n_rail_dof + index
        pad = -c[pad_dof, 2 * ((index + 1) * track.elements_per_bay) - 2]
        assert float(spec.damping[0]) == pytest.approx(c[pad_dof, pad_dof] - pad, rel=1e-12)
    assert float(spec.damping[0]) > 7.9 * track.ballast_damping  # the outermost: x8

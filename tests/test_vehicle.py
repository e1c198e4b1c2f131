"""Several wheels on one rail (issue 17): the coupled loop against independent references."""

from pathlib import Path

import baselines
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse
import scipy.sparse.linalg
from fe_reference import newmark_wheels

import wfjax as wf
from wfjax.contact.laws import prepare
from wfjax.loop.observers import Sensors
from wfjax.loop.run import run_scan
from wfjax.loop.structure import cross_table, structure
from wfjax.model import beam as beam_mod
from wfjax.model import fe as fe_mod
from wfjax.model import supports
from wfjax.model import track as track_mod
from wfjax.model import wheel as wheel_mod
from wfjax.model.vehicle import Vehicle, placement, residual_pairs, transfer_receptance
from wfjax.program.laws import vehicle_laws
from wfjax.scenario.windows import RUN_IN_TIME

F64 = wf.SimConfig(precision="float64")  # identities to rounding: the float64 loop
TRACK = wf.Track(n_bays=baselines.SINGLE_BAYS)  # holds a bogie's wheels as given

REFERENCE = Path(__file__).parent / "data" / "single_wheel_reference.npz"
ROUNDED = wf.Flat.rounded(depth=0.9e-3, length=0.1)
V = 100 / 3.6


@pytest.mark.parametrize("contact", [
    "hertz-profile", "hertz-trajectory", pytest.param("2d", marks=pytest.mark.slow),
    pytest.param("3d", marks=pytest.mark.slow)])
def test_one_wheel_vehicle_reproduces_the_single_wheel_loop(contact, tmp_path, monkeypatch):
    # tests/data holds the histories of the one-wheel loop before the several-wheels rewrite,
    # each contact's from an empty cache: a 3D table built alone (tests/baselines.py)
    if contact == "3d":
        monkeypatch.setenv("WFJAX_CACHE_DIR", str(tmp_path))
    ref = np.load(REFERENCE)
    plain = wf.simulate(ROUNDED, V, contact=contact, impact_position=0.1, config=F64,
                        track=TRACK)
    one = wf.simulate(ROUNDED, V, contact=contact, impact_position=0.1, track=TRACK,
                      vehicle=Vehicle.single(), config=F64)
    for res in (plain, one):
        for key in ("force", "rail_disp", "wheel_disp", "approach"):
            want = ref[f"{contact}/{key}"]
            got = np.asarray(getattr(res, key))
            assert np.max(np.abs(got - want)) <= 1e-9 * np.max(np.abs(want)), key
    assert np.asarray(one.wheel_force).shape == (plain.force.shape[0], 1)


def test_one_wheel_sensors_reproduce_the_single_wheel_loop():
    ref = np.load(REFERENCE)
    res = wf.simulate(ROUNDED, V, contact="hertz-trajectory", impact_position=0.1, track=TRACK,
                      sensors=[0.2, 0.5], sensor_quantities=("shear", "seat_force"), config=F64)
    for q, hist in res.sensors.items():
        want = ref[f"sensors/{q}"]
        assert np.max(np.abs(np.asarray(hist) - want)) <= 1e-9 * np.max(np.abs(want))


def _single_run(flat, x_start, impact, n, dt, config, contact="hertz-trajectory", track=None):
    wheel, track = wf.Wheel(), track or TRACK
    law = prepare(contact, flat, wheel, track, wf.Material(), config)
    struct = structure(Vehicle.single(), [wheel], track, config)
    return run_scan(law, struct, V, dt, x_start, impact, n)


@pytest.mark.slow  # the default run must stay under 10 min (2 cores)
def test_two_wheels_far_apart_each_match_their_single_wheel_run():
    # 20 m apart; modes to 20 kHz (the truncated modal sum's non-causal precursor between
    # wheels this far apart is 0.6 % of P at 10 kHz, 0.08 % at 20 kHz)
    config, track = wf.SimConfig(track_max_frequency=20e3), wf.Track(n_bays=70)
    res = wf.simulate(ROUNDED, V, contact="hertz-trajectory", impact_position=0.1,
                      vehicle=Vehicle((0.0, 20.0)), config=config, track=track)
    x = np.asarray(res.wheel_x)
    n, dt = x.shape[0], float(res.time_step)
    lead = _single_run(ROUNDED, x[0, 0], x[0, 0] - float(res.s[0]), n, dt, config, track=track)
    trail = _single_run(wf.Flat.none(), x[0, 1], x[0, 1] - float(res.s[0]), n, dt, config,
                        track=track)
    t, f = np.asarray(res.t), np.asarray(res.wheel_force)
    after = t >= 0.5 * RUN_IN_TIME
    f_lead = np.asarray(lead["force"])
    assert float(res.wheel_max_force[0]) == pytest.approx(f_lead[after].max(), rel=1e-3)
    assert float(res.wheel_min_force[0]) == pytest.approx(f_lead[after].min(),
                                                          abs=1e-3 * f_lead.max())
    # the smooth wheel runs as if alone until the impact's rail waves reach it (they do:
    # a swing of ~4.7 kN about 13 ms after the impact, the same with modes to 10 kHz)
    before = t < -float(res.s[0]) / V
    assert np.max(np.abs(f[before, 1] - np.asarray(trail["force"])[before])) < 1e-3 * 118e3


def _direct_static(track, positions, loads):
    """Rail deflections [m] under the loads [N] at positions [m]: the FE solve plus each
    load's own deflection inside its element (exact Timoshenko statics)."""
    fe = fe_mod.assemble(track)
    b = fe_mod.load_vector(fe, positions).toarray()
    u = scipy.sparse.linalg.spsolve(fe.stiffness.tocsc(), b @ loads)
    own = beam_mod.element_interior_compliance(track, track_mod.element_fraction(fe, positions))
    return b.T @ u + own * loads


def test_static_deflections_under_several_wheels_superpose_the_direct_solves():
    # three wheels of different loads; the reference wheel on a point of the residual table
    track, config = TRACK, wf.SimConfig().resolved()
    wheels = [wf.Wheel(preload=p) for p in (118e3, 90e3, 140e3)]
    vehicle = Vehicle((0.0, 1.6, 4.1))
    struct = structure(vehicle, wheels, track, config)
    laws = vehicle_laws("hertz-profile", vehicle.flat_list(wf.Flat.none(), lambda i: 0.45),
                           wheels, track, wf.Material(), config)
    x0 = placement(vehicle, 0.65) + 7 * 0.65 / 32
    hist = run_scan(laws, struct, V, 2e-5, x0, x0 + 1.0, 2)
    x = x0 + vehicle.offsets()
    want = _direct_static(track, x, np.array([118e3, 90e3, 140e3]))
    # 5e-4: each wheel's own residual is read from the track's table (8 points per element,
    # linear between them: test_track's test_point_load_inside_an_element_is_exact)
    np.testing.assert_allclose(np.asarray(hist["rail_disp"])[0], want, rtol=5e-4)
    # superposition: the same from three one-wheel direct solves
    singles = sum(_direct_static(track, x, np.eye(3)[i] * w.preload)
                  for i, w in enumerate(wheels))
    np.testing.assert_allclose(want, singles, rtol=1e-12)


VARYING_TRACKS = {"void right of x = 0": lambda: supports.void_sleeper(TRACK,
                                                                       TRACK.n_bays // 2 + 1),
                  "scattered": lambda: supports.scatter(TRACK, 3, cv=0.3)}


@pytest.mark.parametrize("name", list(VARYING_TRACKS))
def test_static_deflections_under_several_wheels_on_varying_supports(name):
    # the pairs' table runs along the whole rail: read at the absolute position, not per bay
    track, config = VARYING_TRACKS[name](), wf.SimConfig()
    wheels = [wf.Wheel(preload=p) for p in (118e3, 90e3)]
    vehicle = Vehicle.bogie()
    struct = structure(vehicle, wheels, track, config)
    laws = vehicle_laws("hertz-profile", vehicle.flat_list(wf.Flat.none(), lambda i: 0.45),
                           wheels, track, wf.Material(), config)
    for x0 in (placement(vehicle, 0.65) + 1.95 + 7 * 0.65 / 32, 2.6 + 0.65 / 32):
        hist = run_scan(laws, struct, V, 2e-5, x0, x0 + 1.0, 2)
        want = _direct_static(track, x0 + vehicle.offsets(), np.array([118e3, 90e3]))
        np.testing.assert_allclose(np.asarray(hist["rail_disp"])[0], want, rtol=5e-4)


def test_cross_table_along_a_varying_track_equals_the_direct_mode_sum():
    track = VARYING_TRACKS["void right of x = 0"]()
    model = track_mod.modal_model(track,
                                  max_frequency=wf.SimConfig().resolved().track_max_frequency)
    offsets = jnp.asarray(Vehicle.bogie().offsets())
    weight = model.weights * jnp.exp(model.poles * 2e-5)  # any per-mode weight

    def shapes_at(x):
        return track_mod.mode_shapes_at(model, x)

    table = cross_table(model, shapes_at, offsets, weight, 0.0)
    grid = track_mod.RESIDUAL_POINTS_PER_ELEMENT * track.elements_per_bay  # points per bay
    for x in (1.3, 2.6 + 33 / grid * 0.65, -4.0625):  # points of the whole-rail grid
        phi = np.asarray(shapes_at(x + offsets))
        direct = np.real(np.sum(np.asarray(weight) * phi[0] * phi[1]))
        got = np.asarray(track_mod.read_residual_table(model, table, x))
        # rounding only: the dampers' pseudo-modes (far above the cut-off, large per-mode terms
        # that cancel) take it from 1e-10 to 6e-9 relative
        np.testing.assert_allclose(got[0, 1], direct, rtol=1e-7)
        assert got[0, 0] == 0.0


def test_residual_pairs_are_symmetric_and_leave_the_diagonal_to_the_tracks_table():
    track, config = TRACK, wf.SimConfig().resolved()
    model = track_mod.modal_model(track, max_frequency=config.track_max_frequency)
    pairs = residual_pairs(track, model, np.array([0.0, -2.5]))
    np.testing.assert_allclose(pairs, np.swapaxes(pairs, 1, 2), rtol=1e-10, atol=1e-22)
    assert np.all(pairs[:, [0, 1], [0, 1]] == 0.0)
    # 2.5 m apart the truncated modes' static coupling is a small remainder of the point's own
    # (about 1 %; either sign since the dampers' pseudo-modes carry part of it)
    assert np.all(np.abs(pairs[:, 0, 1]) < 0.02 * np.mean(np.asarray(model.residual)))
    assert np.any(pairs[:, 0, 1] != 0)


def test_transfer_receptance_is_reciprocal_and_matches_the_direct_solve():
    track = TRACK
    freqs = np.array([20.0, 100.0, 300.0, 800.0, 1500.0])
    a, b = 0.1, -2.4
    direct_ab = track_mod.receptance(track, freqs, x=a, x_response=b)
    direct_ba = track_mod.receptance(track, freqs, x=b, x_response=a)
    np.testing.assert_allclose(direct_ab, direct_ba, rtol=1e-9)
    model = track_mod.modal_model(track, max_frequency=20e3)
    modal_ab = transfer_receptance(track, model, freqs, a, b)
    modal_ba = transfer_receptance(track, model, freqs, b, a)
    np.testing.assert_allclose(modal_ab, modal_ba, rtol=1e-9)
    np.testing.assert_allclose(modal_ab, direct_ab, rtol=0.02)


def test_axle_box_acceleration_is_the_second_derivative_of_the_axle_displacement():
    wheel = wf.Wheel()
    modes = wheel_mod.modal_model(wheel)
    # M_W neither moves nor gains speed at the instant of an impulse on m_W
    assert abs(float(jnp.real(jnp.sum(modes.axle_residues)))) < 1e-15
    assert abs(float(jnp.real(jnp.sum(modes.axle_residues * modes.poles)))) < 1e-12
    res = wf.simulate(ROUNDED, V, contact="hertz-profile", impact_position=0.1,
                      vehicle=Vehicle.bogie())
    # the axle displacement from the same modal states, differentiated twice numerically
    t = np.asarray(res.t)
    f = np.asarray(res.wheel_force)[:, 0]
    dt = t[1] - t[0]
    disp = np.asarray(wheel_mod.response(
        wheel_mod.WheelModal(modes.poles, modes.axle_residues), f - 118e3, dt))
    acc_fd = -(disp[2:] - 2 * disp[1:-1] + disp[:-2]) / dt**2
    acc = np.asarray(res.wheel_axle_acc)[1:-1, 0]
    assert np.max(np.abs(acc_fd - acc)) < 0.02 * np.max(np.abs(acc))
    assert float(res.wheel_axle_acc_peak[0]) > float(res.wheel_axle_acc_peak[1]) > 1.0


def test_bogie_gradient_reaches_the_flat_and_matches_finite_differences():
    wheel, track, config, mat = wf.Wheel(), TRACK, wf.SimConfig(), wf.Material()
    vehicle = Vehicle.bogie()
    struct = structure(vehicle, [wheel, wheel], track, config)
    smooth = prepare("hertz-profile", wf.Flat.none(), wheel, track, mat, config)
    x_imp = placement(vehicle, 0.65) + 0.2
    n, dt = 500, 2.5e-5

    def peak(depth):
        flat = wf.Flat("rounded", depth, 0.1)
        law = prepare("hertz-profile", flat, wheel, track, mat, config)
        hist = run_scan((law, smooth), struct, V, dt, x_imp - 0.3, x_imp, n)
        return jnp.max(hist["force"][:, 0]) + 0.5 * jnp.max(hist["force"][:, 1])

    d0, h = 0.9e-3, 1e-6
    grad = float(jax.grad(peak)(d0))
    fd = (float(peak(d0 + h)) - float(peak(d0 - h))) / (2 * h)
    assert grad == pytest.approx(fd, rel=1e-2)


@pytest.mark.slow
def test_bogie_sweep_gives_every_wheels_extremes():
    # float64: the same run batched and alone agree to rounding (float32 batches differ from
    # a single run by a few ulps, 9e-7 relative, with another fusion of the batched loop)
    speeds, f64 = np.array([60.0, 140.0]) / 3.6, wf.SimConfig(precision="float64")
    sw = wf.sweep(ROUNDED, speeds, 2, contact="hertz-trajectory", vehicle=Vehicle.bogie(),
                  progress=False, config=f64)
    assert sw.wheel_max_force.shape == (1, 2, 2, 2)
    np.testing.assert_array_equal(sw.wheel_max_force[..., 0], sw.max_force)
    res = wf.simulate(ROUNDED, speeds[1], contact="hertz-trajectory", config=f64,
                      impact_position=float(sw.impact_positions[1]), vehicle=Vehicle.bogie())
    np.testing.assert_allclose(sw.wheel_max_force[0, 1, 1], res.wheel_max_force, rtol=1e-9)
    np.testing.assert_allclose(sw.wheel_axle_acc_peak[0, 1, 1], res.wheel_axle_acc_peak,
                               rtol=1e-9)


@pytest.mark.parametrize("kwargs, match", [
    (dict(positions=(0.0, 0.5)), "wheel diameter"),
    (dict(positions=(0.0, 2.5), flat_wheel=2), "flat_wheel"),
    (dict(positions=(0.0, -2.5)), "increase"),
    (dict(repeat_flats=1), "repeat_flats"),
])
def test_bad_vehicles_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        wf.simulate(ROUNDED, V, contact="hertz-profile", vehicle=Vehicle(**kwargs))


def test_a_flat_that_repeats_strikes_again_one_circumference_later():
    """``repeat_flats``: the run is the single strike's until half a circumference later
    (bitwise), the flat strikes again 2 pi R after its first impact, and that strike reads
    what one strike alone reads at the same place within a bay (the track is periodic in
    L_S; the first strike's ringing and the runs' starts differ: within 1 %). Without it the
    wheel rolls on, round."""
    flat, c = wf.Flat.new(0.5e-3), 2 * np.pi * float(wf.Wheel().radius)
    config = wf.SimConfig(run_in=0.3, run_out=c + 0.6)
    once, repeated = (wf.simulate(flat, V, contact="hertz-trajectory", config=config,
                                  vehicle=Vehicle((0.0,), repeat_flats=r)) for r in (False, True))
    s = np.asarray(once.s).ravel()
    f_once, f_rep = np.asarray(once.force).ravel(), np.asarray(repeated.force).ravel()
    first = s < c / 2
    np.testing.assert_array_equal(f_once[first], f_rep[first])
    second, one = np.argmax(np.where(first, 0.0, f_rep)), np.argmax(f_once)
    assert s[second] - s[one] == pytest.approx(c, abs=V * float(np.asarray(once.time_step)))
    alone = wf.simulate(flat, V, contact="hertz-trajectory", impact_position=c - 4 * 0.65,
                        config=wf.SimConfig(run_in=0.3, run_out=0.6))
    assert f_rep[second] == pytest.approx(float(np.max(alone.force)), rel=0.01)
    assert f_rep[second] > 1.5 * float(np.median(f_once))
    assert np.max(f_once[~first]) < 1.05 * float(np.median(f_once))


def test_a_repeated_strike_carries_the_gradient_to_the_flat():
    """``repeat_flats``: over a window that holds only the flat's second strike (2 pi R after
    the first), the peak force's derivative in the flat's depth by ``jax.grad`` equals a
    central finite difference within 1 % (the strike coordinate s - C round(s / C) has
    derivative 1 in s, so the depth reaches the second strike as it does the first)."""
    wheel, track, config, mat = wf.Wheel(), TRACK, wf.SimConfig(), wf.Material()
    struct = structure(Vehicle((0.0,), repeat_flats=True), [wheel], track, config)
    c, x_imp, dt = 2 * np.pi * float(wheel.radius), 0.2, 2.5e-5
    n = int(0.6 / (V * dt))

    def peak(depth):
        law = prepare("hertz-profile", wf.Flat("rounded", depth, 0.1), wheel, track, mat,
                      config)
        hist = run_scan((law,), struct, V, dt, x_imp + c - 0.3, x_imp, n)
        return jnp.max(hist["force"][:, 0])

    d0, h = 0.9e-3, 1e-6
    assert float(peak(d0)) > 1.3 * float(peak(1e-7))  # the second strike is in the window
    grad = float(jax.grad(peak)(d0))
    fd = (float(peak(d0 + h)) - float(peak(d0 - h))) / (2 * h)
    assert grad == pytest.approx(fd, rel=1e-2)


def test_a_detector_reads_each_strike_in_its_own_bays():
    """The loop with the flat striking every revolution (``Vehicle.repeat_flats``) over a
    6-bay detector (3.9 m): a strike in bay 0 strikes again in bay 4, which reads what that
    strike alone reads, and the bays before it what the first strike alone reads, within
    0.5 % (the rule a prediction with every strike would use, docs/identify.md, "Every
    strike"). Without repeats bay 4 reads a round wheel."""
    flat, c, ls, x = wf.Flat.new(0.6e-3), 2 * np.pi * float(wf.Wheel().radius), 0.65, 0.1
    config = wf.SimConfig(precision="float64")

    def read(impact, first_bay, repeat):
        r = wf.simulate(flat, 100 / 3.6, contact="hertz-trajectory", impact_position=impact,
                        detector=wf.Detector(6, first_bay), config=config,
                        vehicle=Vehicle((0.0,), repeat_flats=repeat))
        return np.asarray(r.detector_peak).ravel()

    once, both = read(x, -1, False), read(x, -1, True)
    second = read(x + c - 4 * ls, -5, False)  # the second strike alone, 4 bays earlier
    bays = np.arange(-1, 5)  # the second strike is in bay 4
    expect = np.where(bays >= 4, second, once)
    np.testing.assert_allclose(both, expect, rtol=5e-3)
    assert both[-1] > 1.5 * once[-1]


def test_a_vehicle_too_long_for_a_track_with_per_sleeper_supports_is_refused():
    """Per-sleeper supports fix the track's length (a scalar track is lengthened instead)."""
    track = TRACK
    fixed = wf.supports.with_supports(track, pad_stiffness=np.full(track.n_bays - 1,
                                                                   track.pad_stiffness))
    with pytest.raises(ValueError, match=r"use (track\.)?n_bays >= \d+"):
        wf.simulate(ROUNDED, V, contact="hertz-profile", vehicle=Vehicle((0.0, 40.0)),
                    track=fixed)


def test_bad_wheel_load_is_refused():
    with pytest.raises(ValueError, match="preload"):
        Vehicle((0.0, 2.5), wheels=(wf.Wheel(), wf.Wheel(preload=-1.0)))


# -- an independent reference: the full FE track and two wheels by Newmark integration ------
def _newmark_two_wheels(flat, speed, x_lead, impact, offset, dt, n_steps):
    """Contact forces [n_steps, 2] of two wheels on the full FE track (the flat on the first):
    :func:`fe_reference.newmark_wheels`."""
    return newmark_wheels(flat, speed, x_lead, impact, [0.0, offset], dt, n_steps)


@pytest.mark.slow
def test_two_wheels_agree_with_a_direct_fe_time_integration():
    res = wf.simulate(ROUNDED, V, contact="hertz-profile", impact_position=0.1,
                      vehicle=Vehicle.bogie())
    x = np.asarray(res.wheel_x)
    forces = _newmark_two_wheels(ROUNDED, V, x[0, 0], x[0, 0] - float(res.s[0]), -2.5,
                                 float(res.time_step), x.shape[0])
    after = np.asarray(res.t) >= 0.5 * RUN_IN_TIME
    for i in range(2):
        fm, fn = np.asarray(res.wheel_force)[after, i], forces[after, i]
        assert fn.max() == pytest.approx(fm.max(), rel=0.02), i
        assert fn.min() == pytest.approx(fm.min(), abs=0.02 * fm.max()), i


@pytest.mark.slow
def test_two_wheels_on_a_hanging_sleeper_agree_with_a_direct_fe_time_integration():
    # the impact bay's sleeper hangs (asymmetric track): the vehicle's coupling tables run
    # along the whole rail
    track = supports.void_sleeper(TRACK, TRACK.n_bays // 2)
    res = wf.simulate(ROUNDED, V, contact="hertz-profile", impact_position=0.1,
                      vehicle=Vehicle.bogie(), track=track)
    x = np.asarray(res.wheel_x)
    forces = newmark_wheels(ROUNDED, V, x[0, 0], x[0, 0] - float(res.s[0]), [0.0, -2.5],
                            float(res.time_step), x.shape[0], track=track)
    after = np.asarray(res.t) >= 0.5 * RUN_IN_TIME
    for i in range(2):
        fm, fn = np.asarray(res.wheel_force)[after, i], forces[after, i]
        assert fn.max() == pytest.approx(fm.max(), rel=0.02), i
        assert fn.min() == pytest.approx(fm.min(), abs=0.02 * fm.max()), i


@pytest.mark.slow
def test_sensors_and_detector_see_every_wheel():
    # static start: the readings under a bogie are the superposition of each wheel's alone
    from wfjax.scenario import sensors as sensor_mod
    from wfjax.scenario.sensors import Detector

    track, config, wheel = TRACK, wf.SimConfig(), wf.Wheel()
    vehicle = Vehicle.bogie()
    struct = structure(vehicle, [wheel, wheel], track, config)
    smooth = prepare("hertz-profile", wf.Flat.none(), wheel, track, wf.Material(), config)
    spec = sensor_mod.sensor_spec([-1.3, 0.0, 0.2], track, struct.track,
                                  ("rail_disp", "shear", "seat_force"))
    x0 = placement(vehicle, 0.65) + 0.1
    both = run_scan((smooth, smooth), struct, V, 2e-5, x0, x0 + 1.0, 2,
                    observers=(Sensors(spec),))
    one = structure(Vehicle.single(), [wheel], track, config)
    alone = [run_scan(smooth, one, V, 2e-5, x, x + 1.0, 2,
                      observers=(Sensors(spec),))["sensors"][0] for x in x0 + vehicle.offsets()]
    np.testing.assert_allclose(np.asarray(both["sensors"][0]), np.asarray(sum(alone)),
                               rtol=1e-6, atol=1e-9 * 118e3)
    res = wf.simulate(ROUNDED, V, contact="hertz-trajectory", vehicle=vehicle,
                      detector=Detector(n_bays=3))
    peak = np.asarray(res.detector_peak)
    assert peak.shape == (2, 3)  # each wheel's peak in each bay it crosses
    assert np.all(np.abs(peak[1] / 118e3 - 1) < 0.2)  # the smooth wheel reads about P


@pytest.mark.parametrize("argv, words", [
    (["--wheel-positions-m", "0,0.5"], "wheel diameter"),
    (["--vehicle", "bogie", "--flat-wheel", "2"], "flat_wheel"),
    (["--vehicle", "tram"], "allowed: single | bogie | wagon"),
    (["--vehicle", "bogie", "--axle-spacing-m", "40"], "allowed: [0.3, 10] m"),
])
def test_cli_refuses_bad_vehicles_with_one_line(tmp_path, capsys, argv, words):
    from wfjax.cli import main

    out = tmp_path / "out"
    assert main(["simulate", "--contact", "hertz-profile", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and words in err, err
    assert not out.exists()


def test_off_the_rail_names_a_length_that_holds_the_wheels():
    """check_on_track's one line names the least even n_bays that holds the wheels' span
    either side of x = 0 (it named one that could be the refused length), and that length
    passes."""
    from wfjax.model.vehicle import check_on_track

    veh, track = wf.Vehicle.preset("bogie"), wf.Track(n_bays=10)
    with pytest.raises(ValueError, match=r"beyond the rail .* use track.n_bays >= 12$") as e:
        check_on_track(veh, track, 0.69, 3.54)  # the wheels over [-1.81, 3.54] m
    assert "\n" not in str(e.value)
    check_on_track(veh, wf.Track(n_bays=12), 0.69, 3.54)

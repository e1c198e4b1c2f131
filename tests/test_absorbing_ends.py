"""Absorbing track ends (Track.absorbing_sleepers, wfjax.model.fe.end_grading): the last
sleepers' damping graded up absorbs the waves the clamped ends reflect back to the wheel."""

import numpy as np
import pytest

import wfjax as wf
from wfjax.model import fe as fe_mod
from wfjax.model import track as track_mod
from wfjax.model.fe import END_GRADING, end_grading
from wfjax.model.periodic import periodic_receptance
from wfjax.scenario import guards
from wfjax.scenario import sensors as sensor_mod


def test_grading_is_geometric_to_the_outermost_sleeper():
    g = end_grading(10, 3)
    np.testing.assert_allclose(g, [8, 4, 2, 1, 1, 1, 1, 2, 4, 8])
    assert g[0] == END_GRADING
    np.testing.assert_array_equal(end_grading(10, 0), np.ones(10))


def test_too_many_absorbing_sleepers_are_refused_by_name():
    # checked on the assembled (lengthened) track: a short Track is a least length
    wf.Track(n_bays=4)
    with pytest.raises(ValueError, match="absorbing_sleepers = 12 needs at least 24"):
        fe_mod.assemble(wf.Track(n_bays=24, absorbing_sleepers=12))
    fe_mod.assemble(wf.Track(n_bays=25, absorbing_sleepers=12))
    with pytest.raises(ValueError, match="absorbing_sleepers must be an integer"):
        wf.Track(absorbing_sleepers=-1)


def test_wheels_and_sensors_keep_off_the_absorbing_sleepers():
    track = wf.Track(absorbing_sleepers=6)
    assert guards.end_margin(track) >= 7 * 0.65
    assert guards.sensor_margin(track) >= guards.end_margin(track)
    assert guards.end_margin(wf.Track(absorbing_sleepers=0)) == pytest.approx(
        guards.END_FACTOR * guards.decay_length(track))


def _min_force_20kmh(n_bays: int, absorbing: int) -> float:
    cfg = wf.SimConfig(precision="float64")
    track = wf.Track.comparison(n_bays=n_bays, absorbing_sleepers=absorbing)
    r = wf.simulate(wf.Flat.new(0.9e-3), 20 / 3.6, contact="hertz-trajectory",
                    impact_position=0.065, track=track, config=cfg)
    return float(r.min_force)


def test_the_short_track_reads_the_long_ones_min_force():
    # 20 km/h, new 0.9 mm flat: the minimum comes from the rebound ~10 ms after the impact,
    # when the clamped ends' reflections are back (docs/convergence.md, "Min force")
    static = float(wf.Wheel().preload)
    long = _min_force_20kmh(50, 3)
    assert abs(_min_force_20kmh(24, 3) - long) < 1e-3 * static
    assert abs(_min_force_20kmh(24, 0) - long) > 1e-2 * static  # the clamped ends' error
    assert abs(_min_force_20kmh(50, 0) - long) < 1e-3 * static  # the long track is converged


def test_receptance_comes_closer_to_the_infinite_track():
    f = np.linspace(20.0, 2000.0, 200)
    h_inf = periodic_receptance(wf.Track(), f, 0.3, 1.0)
    err = {}
    for n in (0, 3):
        track = wf.Track(absorbing_sleepers=n)
        model = track_mod.modal_model(track, max_frequency=15e3)
        h = sensor_mod.transfer_receptance(track, model, f, 0.3, 1.0)
        err[n] = np.median(np.abs(h - h_inf) / np.abs(h_inf))
    assert err[3] < 0.5 * err[0], err

"""Absorbing track ends (Track.absorbing_sleepers, wfjax.model.fe.end_grading): the last
sleepers' damping graded up absorbs the waves the clamped ends reflect back to the wheel."""

import numpy as np
import pytest

import wfjax as wf
from wfjax.model import beam as beam_mod
from wfjax.model import fe as fe_mod
from wfjax.model import track as track_mod
from wfjax.model.fe import END_GRADING, end_grading
from wfjax.model.periodic import periodic_receptance
from wfjax.scenario import guards
from wfjax.scenario import sensors as sensor_mod


def absorbing(**kw) -> wf.Track:
    return wf.Track(**{"ends": "absorbing", **kw})


def test_grading_is_geometric_to_the_outermost_sleeper():
    g = end_grading(10, 3)
    np.testing.assert_allclose(g, [8, 4, 2, 1, 1, 1, 1, 2, 4, 8])
    assert g[0] == END_GRADING
    np.testing.assert_array_equal(end_grading(10, 0), np.ones(10))


def test_the_rail_is_damped_over_the_absorbing_zone_only():
    """The rail's block of C is eta(x) M_rail plus the (graded) pads on the rail dofs above
    the sleepers, eta quadratic from 0 at the zone's inner edge to END_RAIL_DAMPING at the
    ends, and no rail damping without absorbing sleepers."""
    for n in (3, 0):
        track = absorbing(n_bays=10, elements_per_bay=4, absorbing_sleepers=n)
        fe = fe_mod.assemble(track)
        ne, nr = 40, fe.n_rail_dof
        _, me, _ = beam_mod.element_matrices(track.bending_stiffness, track.shear_stiffness,
                                           track.rail_mass, track.rail_rotary_inertia,
                                           fe.element_length)
        eta = (fe_mod.end_rail_damping((np.arange(ne) + 0.5) * fe.element_length, 6.5, 2.6)
               if n else np.zeros(ne))
        m = np.zeros((nr + 4, nr + 4))  # the eta-weighted rail mass, clamped end dofs too
        for e in range(ne):
            m[2 * e:2 * e + 4, 2 * e:2 * e + 4] += eta[e] * me
        pads = np.zeros((nr, nr))
        j = 8 * np.arange(1, 10) - 2  # the rail's w dofs above the 9 sleepers
        pads[j, j] = track.pad_damping * fe_mod.end_grading(9, n)
        c = fe.damping.toarray()[:nr, :nr]
        np.testing.assert_allclose(c, m[2:-2, 2:-2] + pads, atol=1e-9 * np.abs(c).max())
    assert fe_mod.end_rail_damping([0.0, 1.3, 2.6, 3.0], 6.5, 2.6).tolist() == [
        fe_mod.END_RAIL_DAMPING, fe_mod.END_RAIL_DAMPING / 4, 0.0, 0.0]


def test_too_many_absorbing_sleepers_are_refused_by_name():
    # checked on the assembled (lengthened) track: a short Track is a least length
    absorbing(n_bays=4, absorbing_sleepers=12)
    with pytest.raises(ValueError, match="absorbing_sleepers = 12 needs at least 24"):
        fe_mod.assemble(absorbing(n_bays=24, absorbing_sleepers=12))
    fe_mod.assemble(absorbing(n_bays=25, absorbing_sleepers=12))
    with pytest.raises(ValueError, match="absorbing_sleepers must be an integer"):
        absorbing(absorbing_sleepers=-1)


def test_wheels_and_sensors_keep_off_the_absorbing_sleepers():
    track = absorbing(n_bays=24, absorbing_sleepers=6)
    assert guards.end_margin(track) >= 7 * 0.65
    assert guards.sensor_margin(track) >= guards.end_margin(track)
    assert guards.end_margin(absorbing(n_bays=24, absorbing_sleepers=0)) == pytest.approx(
        guards.END_FACTOR * guards.decay_length(track))


def _min_force_20kmh(n_bays: int, absorbing: int) -> float:
    cfg = wf.SimConfig(precision="float64")
    track = wf.Track.comparison(ends="absorbing", n_bays=n_bays, absorbing_sleepers=absorbing)
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
    h_inf = periodic_receptance(wf.Track(), f, 0.3, 1.0)  # no ends
    err = {}
    for n in (0, 3):
        track = absorbing(n_bays=24, absorbing_sleepers=n)
        model = track_mod.modal_model(track, max_frequency=15e3)
        h = sensor_mod.transfer_receptance(track, model, f, 0.3, 1.0)
        err[n] = np.median(np.abs(h - h_inf) / np.abs(h_inf))
    assert err[3] < 0.5 * err[0], err


@pytest.mark.slow
def test_the_short_track_reads_the_long_ones_rebound_in_3d():
    """The 3D new flat at 20 km/h, whose minimum is the rebound 6-10 ms after the impact, when
    the ends' waves near the pinned-pinned frequency are back: on 24 bays within 0.5 % of the
    static load of 70 bays' at every impact position (0.73 kN apart, 0.62 %, with the sleepers'
    grading alone; the rail's end damping halves it)."""
    cfg = wf.SimConfig(track_max_frequency=20e3, precision="float64")

    def min_force(n_bays):
        r = wf.sweep(wf.Flat.new(0.9e-3), np.array([20 / 3.6]), 5, contact="3d",
                     track=wf.Track.comparison(ends="absorbing", n_bays=n_bays), config=cfg,
                     progress=False)
        return np.asarray(r.min_force)[0, 0]

    assert np.max(np.abs(min_force(24) - min_force(70))) < 5e-3 * float(wf.Wheel().preload)

"""The run's time grid puts a step where the flat's centre meets the contact point
(wfjax.scenario.windows, "Time grid"), so a new flat's minimum force, at its trajectory's
kink, does not depend on the step."""

import numpy as np
import pytest

import wfjax as wf
from wfjax.scenario.windows import (
    aligned_time_step,
    batch_windows,
    n_steps_for,
    simulation_window,
)

CONFIG = wf.SimConfig()


@pytest.mark.parametrize("speed_kmh", [20.0, 37.0, 90.0, 143.0, 300.0])
def test_a_step_lands_on_the_flat_centre_within_the_cap(speed_kmh):
    flat, v = wf.Flat.new(0.9e-3), speed_kmh / 3.6
    s0, s1 = simulation_window(flat, v, CONFIG)
    n, dt = n_steps_for(flat, v, CONFIG)
    k = -s0 / (v * dt)
    assert abs(k - round(k)) < 1e-6  # s = 0 is step round(k)
    assert dt <= CONFIG.time_step_for(v) * (1 + 1e-12)
    assert s0 + (n - 1) * v * dt >= s1 - 1e-12  # the window is covered
    assert s0 + (n - 2) * v * dt < s1  # with no step to spare


def test_a_batch_of_speeds_shares_the_step_count_and_aligns_each():
    flat, v = wf.Flat.rounded(0.9e-3, 0.1), np.array([30.0, 80.0, 200.0]) / 3.6
    n, dt, s0, _ = batch_windows(flat, v, CONFIG)
    for vj, dtj, s0j in zip(v, dt, s0, strict=True):
        k = -s0j / (vj * dtj)
        assert abs(k - round(k)) < 1e-6
        assert dtj <= n_steps_for(flat, vj, CONFIG)[1] * (1 + 1e-12)
        assert s0j + (n - 1) * vj * dtj >= simulation_window(flat, vj, CONFIG)[1] - 1e-12
    # one speed: the batch's grid is simulate's
    n1, dt1, _, _ = batch_windows(flat, v[:1], CONFIG)
    assert (n1, dt1[0]) == pytest.approx(n_steps_for(flat, v[0], CONFIG))


def test_too_few_steps_to_align_keep_the_plain_step():
    assert aligned_time_step(-0.1, 0.9, 10.0, 3) == pytest.approx(1.0 / 10.0 / 2)


def test_the_new_flats_min_force_does_not_depend_on_the_step():
    # 40 km/h, just below loss of contact: the force falls linearly to its minimum at the
    # kink (s = 0); a grid straddling it read 1.5-2 kN high at 40 us (docs/convergence.md)
    track = wf.Track.comparison()
    mins = []
    for step in (40e-6, 12.5e-6):
        cfg = wf.SimConfig(max_time_step=step, precision="float64")
        r = wf.simulate(wf.Flat.new(0.9e-3), 40 / 3.6, contact="hertz-trajectory",
                        impact_position=0.065, track=track, config=cfg)
        s = np.asarray(r.s)
        assert np.min(np.abs(s)) < 1e-9  # a step at the flat's centre
        assert abs(s[np.argmin(np.asarray(r.force))]) < 1e-9  # the minimum there
        mins.append(float(r.min_force))
    static = float(wf.Wheel().preload)
    assert abs(mins[0] - mins[1]) < 1e-3 * static


def test_the_coupled_runs_step_lands_on_the_leading_flat_and_covers_the_window():
    from wfjax.identify import forward as fwd

    v, det = 100 / 3.6, wf.Detector(5, -fwd.REACH)
    positions = np.array([0.0, 2.5])
    w = fwd._window(det, fwd.TRACK, wf.Wheel(), fwd.identification_config(None), positions, v)
    for impact in (w.x0 + 0.5 * w.lead_in, 0.0, 1.3, 3.0):
        dt = w.step(impact, v)
        k = (impact - w.x0) / (v * dt)
        assert abs(k - round(k)) < 1e-6 and dt <= w.max_step * (1 + 1e-12)
        assert w.x0 + (w.n_steps - 1) * v * dt >= w.x1  # the window is covered
    assert w.step(w.x0 + 0.1 * w.lead_in, v) == w.max_step  # too close to align

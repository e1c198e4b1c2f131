"""The loop's static start when a wheel starts on its flat (no contact at a small approach):
the static approach's Newton steps are bounded, so the start is the wheel resting in its
flat, not an approach of 125 km that sent a 3D table law's run to 1e11 N."""

from __future__ import annotations

import math

import jax
import numpy as np
import pytest

from wfjax.contact.newton import STATIC_STEP_MAX, static_approach

jax.config.update("jax_enable_x64", True)
C_H = 1.0e11  # N / m^1.5, a Hertz constant of the wheel/rail order
P = 125e3  # N


@pytest.mark.parametrize("onset", [0.0, 2.6e-3, 4.6e-3])
def test_static_approach_finds_the_root_beyond_a_flats_depth(onset):
    """F = C_H clip(delta - onset, 0, 1 mm)^1.5: a wheel on a flat of depth ``onset`` (no
    contact below it) with a law tabulated over a finite compression (constant beyond it,
    as a table read past its end). The approach is onset + (P / C_H)^(2/3) to 1e-12 m, up
    to the deepest parametric flat's 4.6 mm (a new 130 mm flat). Unbounded, the first step
    (P / 1 N/m) left the table and the iterates never came back (checked: 30 steps
    without converging for both flats)."""
    def force(d):
        return C_H * jax.numpy.clip(d - onset, 0.0, 1e-3) ** 1.5

    got = float(static_approach(force, P))
    assert got == pytest.approx(onset + (P / C_H) ** (2 / 3), abs=1e-12)


def test_a_round_wheels_static_steps_are_not_bounded():
    """A round wheel's first step from 10 um rises far less than the bound: its start is
    what it was before the bound."""
    d = 1e-5
    rise = (P - C_H * d ** 1.5) / (1.5 * C_H * math.sqrt(d))
    assert rise < 0.5 * STATIC_STEP_MAX


@pytest.mark.slow
@pytest.mark.parametrize("offset", [-0.02, 0.02])
def test_a_3d_run_that_starts_on_its_flat_reads_as_one_that_does_not(offset):
    """A new 97.5 mm flat (exact 3D table) whose earlier strike falls 2 cm from where its
    wheel starts (60 km/h; before the bound: 6.5e11 and 6.7e11 N): the peak contact force
    within 5 % of the same flat struck 20 cm after the start."""
    from wfjax import Wheel
    from wfjax.identify import forward as fwd
    from wfjax.scenario.sensors import Detector

    wheel, det, speed = Wheel(), Detector(5, -1), 60 / 3.6
    x0 = fwd._window(det, fwd.TRACK, wheel, fwd.identification_config(None),
                     np.array([0.0]), speed)[0]
    circ = 2 * math.pi * float(wheel.radius)
    flat = fwd.flat_of("new", 0.0975, 1.0, float(wheel.radius))
    peaks = [fwd.coupled_batch([([flat], [x0 + off + 2 * circ])], np.array([0.0]), speed, det,
                               "3d")[1][0, 0] for off in (offset, 0.2)]
    assert peaks[0] == pytest.approx(peaks[1], rel=0.05)

"""Flat geometry (Section 2, Eqs. 1-3) and the rigid wheel-centre trajectory."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wfjax as wf
from wfjax.model import geometry

R = 0.45
D = 0.9e-3


def test_eq1_length_of_new_flat():
    assert wf.params.new_flat_length(D, R) == pytest.approx(np.sqrt(8 * R * D), rel=1e-15)
    assert wf.params.new_flat_length(D, R) == pytest.approx(0.056921, abs=1e-6)


def test_new_flat_exact_chord_at_chosen_points():
    flat = wf.Flat.new(D)
    # centre: full depth; exact chord end at R arccos(1 - d/R): zero
    alpha = np.arccos(1 - D / R)
    x = np.array([0.0, 0.01, R * alpha - 1e-9, R * alpha + 1e-6, 0.05])
    z = np.asarray(geometry.profile_deviation(flat, x))
    expected = np.maximum(R - (R - D) / np.cos(x / R), 0.0)
    np.testing.assert_allclose(z, expected, atol=1e-15)
    assert z[0] == pytest.approx(D, abs=1e-15)
    assert z[-1] == 0.0


def test_eq2_is_small_depth_form_of_exact_chord():
    flat = wf.Flat.new(D)
    x = np.linspace(-0.027, 0.027, 101)
    exact = np.asarray(geometry.profile_deviation(flat, x))
    small = np.asarray(geometry.profile_deviation_small_depth(flat, x))
    diff = np.abs(exact - small)
    # documented bound d^2/R + x^4/(3 R^3); and the difference is not zero (they are different)
    assert np.all(diff <= D**2 / R + x**4 / (3 * R**3) + 1e-12)
    assert diff.max() > 1e-7
    # Eq. 2 at chosen points
    assert small[50] == pytest.approx(D)
    assert float(geometry.profile_deviation_small_depth(flat, 0.02)) == pytest.approx(
        D - 0.02**2 / (2 * R))


def test_eq3_rounded_flat_at_chosen_points():
    flat = wf.Flat.rounded(D, 0.1)
    x = np.array([0.0, 0.025, 0.05, 0.06, -0.0125])
    z = np.asarray(geometry.profile_deviation(flat, x))
    np.testing.assert_allclose(z, [D, D / 2, 0.0, 0.0, D / 2 * (1 + np.cos(np.pi / 4))],
                               atol=1e-16)


def test_rounded_at_least_as_deep_as_new_iff_long_enough():
    l0 = wf.params.new_flat_length(D, R)
    x = np.linspace(-0.04, 0.04, 2001)
    z_new = np.asarray(geometry.profile_deviation_small_depth(wf.Flat.new(D), x))
    z_ok = np.asarray(geometry.profile_deviation(wf.Flat.rounded(D, np.pi / 2 * l0), x))
    assert np.all(z_ok >= z_new - 1e-12)
    # counter-example below pi/2 l0 (constructed directly; the constructor refuses it)
    short = wf.Flat("rounded", depth=D, length=1.3 * l0)
    z_short = np.asarray(geometry.profile_deviation(short, x))
    assert np.any(z_short < z_new - 1e-6)


def test_new_flat_trajectory_pivots_on_edges():
    flat = wf.Flat.new(D)
    alpha = np.arccos(1 - D / R)
    x = np.linspace(-R * alpha, R * alpha, 401)
    traj = np.asarray(geometry.centre_trajectory(flat, x))
    expected = -R * (1 - np.cos(alpha - np.abs(x) / R))
    np.testing.assert_allclose(traj, expected, atol=1e-9, rtol=0)
    # the documented approximation -(l0/2 - |x|)^2 / (2R)
    l0 = wf.params.new_flat_length(D, R)
    np.testing.assert_allclose(traj, -((l0 / 2 - np.abs(x)) ** 2) / (2 * R), atol=2e-6)
    # outside the flat the wheel is round
    assert np.all(np.asarray(geometry.centre_trajectory(flat, np.array([-0.05, 0.05]))) == 0)


@pytest.mark.parametrize("length", [0.080, 0.083])
def test_deep_new_flat_trajectory_has_no_stray_maximiser(length):
    """The pivot formula at every point of the Hertz-trajectory law's grid (2e-5 m steps from
    0) of new flats 80 and 83 mm long on a 0.45 m wheel with the identification's extent
    bound. The Newton polish of the maximiser once jumped off the chord (near-zero curvature)
    to theta of order 1e4 rad, where r(theta) cos(theta - phi) is a round radius at an angle
    near phi + 2 pi k: at x = +-0.1 mm the drop read 0.10 instead of 1.77 mm (a single-step
    1,465 kN spike in a run over it)."""
    radius = 0.45
    depth = length**2 / (8 * radius)
    flat = wf.Flat("new", depth=depth, length=length, wheel_radius=radius, extent_bound=0.065)
    alpha = np.arccos(1 - depth / radius)
    x = np.arange(-int(radius * alpha / 2e-5), int(radius * alpha / 2e-5) + 1) * 2e-5
    traj = np.asarray(geometry.centre_trajectory(flat, x))
    np.testing.assert_allclose(traj, -radius * (1 - np.cos(alpha - np.abs(x) / radius)),
                               atol=1e-9, rtol=0)


def test_rounded_trajectory_reaches_depth_and_stays_above_profile():
    flat = wf.Flat.rounded(D, 0.1)
    x = np.linspace(-0.06, 0.06, 601)
    traj = np.asarray(geometry.centre_trajectory(flat, x))
    z = np.asarray(geometry.profile_deviation(flat, x))
    assert traj[300] == pytest.approx(-D, abs=1e-12)
    assert np.all(traj >= -z - 1e-12)
    # narrower than the profile: strictly above it on the flanks
    assert traj[200] > -z[200] + 1e-5


def test_trajectory_of_measured_profile_matches_analytic_flat():
    rounded = wf.Flat.rounded(D, 0.1)
    xs = np.linspace(-0.05, 0.05, 2001)
    measured = wf.Flat.from_profile(xs, np.asarray(geometry.profile_deviation(rounded, xs)))
    x = np.linspace(-0.05, 0.05, 41)
    np.testing.assert_allclose(geometry.centre_trajectory(measured, x),
                               geometry.centre_trajectory(rounded, x), atol=2e-8)


def _central_fd(f, p, h):
    return (f(p + h) - f(p - h)) / (2 * h)


@pytest.mark.parametrize("kind", ["new", "rounded"])
def test_gradients_match_finite_differences(kind):
    x = jnp.array([-0.03, -0.012, 0.0, 0.007, 0.02])

    def make(depth, length):
        if kind == "new":
            return wf.Flat("new", depth=depth, length=length)
        return wf.Flat("rounded", depth=depth, length=length)

    for fn in (geometry.centre_trajectory, geometry.profile_deviation):
        def total(depth, length, fn=fn):
            return jnp.sum(fn(make(depth, length), x) * jnp.arange(1, 6))

        g_d, g_l = jax.grad(total, argnums=(0, 1))(D, 0.1)
        fd_d = _central_fd(lambda d, fn=fn: total(d, 0.1, fn), D, 1e-6)
        np.testing.assert_allclose(g_d, fd_d, rtol=1e-5, atol=1e-9)
        if kind == "rounded":
            fd_l = _central_fd(lambda l, fn=fn: total(D, l, fn), 0.1, 1e-5)
            np.testing.assert_allclose(g_l, fd_l, rtol=1e-5, atol=1e-9)


def test_flat_surface_is_imprint_of_rail_head():
    flat = wf.Flat.rounded(D, 0.1)
    x = np.linspace(-0.06, 0.06, 121)
    y = np.linspace(-0.04, 0.04, 81)
    surf = np.asarray(geometry.flat_surface(flat, x, y, 0.30))
    assert surf.shape == (121, 81)
    # centre line equals the 2D profile; transverse lines are arcs of radius 0.30 m
    np.testing.assert_allclose(surf[:, 40], geometry.profile_deviation(flat, x), atol=1e-16)
    arc = 0.30 - np.sqrt(0.30**2 - y**2)
    np.testing.assert_allclose(surf[60], np.maximum(D - arc, 0), atol=1e-16)
    # width of the flat at its centre: 2 sqrt(2 R_R d) approximately
    width = np.ptp(y[surf[60] > 0])
    assert width == pytest.approx(2 * np.sqrt(2 * 0.30 * D), abs=2e-3)
    g = jax.grad(lambda d: jnp.sum(geometry.flat_surface(wf.Flat("new", d, 0.0), x, y, 0.3)))(D)
    assert np.isfinite(g) and g > 0


def test_no_flat_is_zero():
    flat = wf.Flat.none()
    assert float(jnp.max(geometry.profile_deviation(flat, jnp.linspace(-1, 1, 11)))) == 0
    assert float(jnp.min(geometry.centre_trajectory(flat, jnp.linspace(-1, 1, 11)))) == 0

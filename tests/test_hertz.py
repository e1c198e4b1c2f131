"""Hertz contact spring (Eqs. 14-15): reference numbers, inverse, safe gradients, transforms."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from wfjax import Material
from wfjax.contact import hertz

MAT = Material()
R = 0.45
F_STATIC = 118e3


def _force_of(delta, youngs_modulus, poisson_ratio, radius):
    return hertz.force(delta, Material(youngs_modulus, poisson_ratio), radius)


def test_hertz_constant_value():
    expected = 2.0 / 3.0 * 210e9 / (1 - 0.3**2) * math.sqrt(0.45)
    assert float(hertz.hertz_constant(MAT, R)) == pytest.approx(expected, rel=1e-14)


def test_reference_numbers_at_static_load():
    # formulas.md: 118 kN, R = 0.45 m -> delta 0.1093 mm, a 7.01 mm, p0 1145 MPa.
    delta = float(hertz.approach_for_force(F_STATIC, MAT, R))
    assert delta * 1e3 == pytest.approx(0.1093, abs=5e-5)
    assert float(hertz.contact_radius(delta, R)) * 1e3 == pytest.approx(7.01, abs=5e-3)
    assert float(hertz.max_pressure(F_STATIC, MAT, R)) / 1e6 == pytest.approx(1145, abs=0.5)
    # p0 from its definition 3F / (2 pi a^2)
    a = float(hertz.contact_radius(delta, R))
    assert float(hertz.max_pressure(F_STATIC, MAT, R)) == pytest.approx(
        3 * F_STATIC / (2 * math.pi * a**2), rel=1e-12
    )


def test_inverse_round_trip():
    forces = jnp.array([0.0, 1.0, 1e3, 118e3, 500e3, 2e6])
    delta = hertz.approach_for_force(forces, MAT, R)
    np.testing.assert_allclose(hertz.force(delta, MAT, R), forces, rtol=1e-13, atol=1e-9)
    deltas = jnp.array([-1e-4, 0.0, 1e-7, 1e-4, 1e-3])
    back = hertz.approach_for_force(hertz.force(deltas, MAT, R), MAT, R)
    np.testing.assert_allclose(back, jnp.maximum(deltas, 0.0), rtol=1e-12, atol=1e-18)


def test_zero_force_without_contact():
    np.testing.assert_array_equal(hertz.force(jnp.array([-1e-3, -1e-9, 0.0]), MAT, R), 0.0)


@pytest.mark.parametrize("delta", [0.0, -1e-4])
def test_gradients_finite_at_zero_and_negative_approach(delta):
    d1 = jax.grad(hertz.force)(delta, MAT, R)
    d2 = jax.grad(jax.grad(hertz.force))(delta, MAT, R)
    assert float(d1) == 0.0 and float(d2) == 0.0
    # (material leaves are differentiated through a Material built inside: the cotangent
    # Material that jax.grad would return is re-validated by params.py and rejected)
    g_e, g_nu, g_r = jax.grad(_force_of, argnums=(1, 2, 3))(delta, 210e9, 0.3, R)
    assert float(g_e) == 0.0 and float(g_nu) == 0.0 and float(g_r) == 0.0
    assert float(jax.grad(hertz.approach_for_force)(0.0, MAT, R)) == 0.0
    assert float(jax.grad(hertz.contact_radius)(delta, R)) == 0.0


def test_gradient_matches_analytic_and_finite_differences():
    delta = 1.2e-4
    c_h = float(hertz.hertz_constant(MAT, R))
    g = float(jax.grad(hertz.force)(delta, MAT, R))
    assert g == pytest.approx(1.5 * c_h * math.sqrt(delta), rel=1e-13)
    f, k = hertz.force_and_stiffness(delta, MAT, R)
    assert float(f) == pytest.approx(float(hertz.force(delta, MAT, R)), rel=1e-14)
    assert float(k) == pytest.approx(g, rel=1e-13)
    # radius and Young's modulus by central differences
    g_r = float(jax.grad(hertz.force, argnums=2)(delta, MAT, R))
    eps = 1e-6
    fd_r = (float(hertz.force(delta, MAT, R + eps)) - float(hertz.force(delta, MAT, R - eps))) / (
        2 * eps
    )
    assert g_r == pytest.approx(fd_r, rel=1e-7)
    g_e = jax.grad(_force_of, argnums=1)(delta, 210e9, 0.3, R)
    fd_e = (
        float(hertz.force(delta, Material(210e9 + 1e3), R))
        - float(hertz.force(delta, Material(210e9 - 1e3), R))
    ) / 2e3
    assert float(g_e) == pytest.approx(fd_e, rel=1e-7)
    # inverse: d delta / dF = 1 / (dF / d delta)
    g_inv = float(jax.grad(hertz.approach_for_force)(F_STATIC, MAT, R))
    d_static = hertz.approach_for_force(F_STATIC, MAT, R)
    assert g_inv == pytest.approx(1 / float(jax.grad(hertz.force)(d_static, MAT, R)), rel=1e-12)


def test_jit_and_vmap_match_loop():
    deltas = jnp.linspace(-5e-5, 3e-4, 17)
    radii = jnp.linspace(0.3, 0.5, 17)
    batched = jax.jit(jax.vmap(hertz.force, in_axes=(0, None, 0)))(deltas, MAT, radii)
    looped = np.array([float(hertz.force(d, MAT, r)) for d, r in zip(deltas, radii, strict=True)])
    np.testing.assert_allclose(batched, looped, rtol=1e-14)
    # traced inputs are not validated (no error under jit)
    assert float(jax.jit(hertz.force)(-1.0, MAT, R)) == 0.0


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda: hertz.force(float("nan"), MAT, R), "approach"),
        (lambda: hertz.force(1e-4, MAT, 0.0), "radius"),
        (lambda: hertz.force(1e-4, MAT, -0.45), "radius"),
        (lambda: hertz.hertz_constant(MAT, float("inf")), "radius"),
        (lambda: hertz.approach_for_force(-1.0, MAT, R), "force"),
        (lambda: hertz.max_pressure(float("nan"), MAT, R), "force"),
    ],
)
def test_bad_input_raises(call, name):
    with pytest.raises(ValueError, match=rf"^{name} must be finite and in .*got"):
        call()

"""2D Winkler bedding (Eqs. 11-13): Hertz calibration, flats, continuity, transforms, errors."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import quad

from wfjax import Flat, Material
from wfjax.contact import hertz
from wfjax.contact import winkler as wk

MAT = Material()
R = 0.45
K = 210e9 / (2 * math.sqrt(2) * (1 - 0.3**2))
DELTA_STATIC = float(hertz.approach_for_force(118e3, MAT, R))  # 0.1093 mm

# Measured (1 mm elements, exact circle): the bedding force of a smooth wheel is below Hertz
# by 0.259 % at 118 kN; over approaches of 0.05-1 mm the deficit is
# h^2 / (8 R delta) + 0.15 delta / R within 5 % (linear interpolation of the concave profile,
# plus the circle's departure from the parabola), e.g. 0.56 % at 0.05 mm, 0.06 % at 1 mm.
TOL_STATIC_1MM = 3e-3


def _z_w(x):
    return R - math.sqrt(R * R - x * x)


def _quad_force(profile, delta, half):
    """k int max(0, delta - z_W(x) - profile(x)) dx by adaptive quadrature (independent)."""
    xs = np.linspace(-half, half, 20001)
    inside = xs[[delta - _z_w(x) - profile(x) > 0 for x in xs]]
    lo, hi = inside.min() - 1e-4, inside.max() + 1e-4
    val, _ = quad(lambda x: max(0.0, delta - _z_w(x) - profile(x)), lo, hi,
                  epsabs=0.0, epsrel=1e-12, limit=1000)
    return K * val


def test_stiffness_value():
    assert float(wk.winkler_stiffness(MAT)) == pytest.approx(K, rel=1e-14)


def test_parabolic_bedding_is_hertz_exactly():
    # The paper's calibration: k int max(0, delta - x^2/(2R)) dx = C_H delta^1.5.
    for delta in (2e-5, DELTA_STATIC, 1e-3):
        b = math.sqrt(2 * R * delta)
        val, _ = quad(lambda x, d=delta: d - x * x / (2 * R), -b, b, epsabs=0, epsrel=1e-13)
        assert K * val == pytest.approx(float(hertz.force(delta, MAT, R)), rel=1e-11)


@pytest.mark.slow
def test_discrete_parabola_converges_to_hertz_at_second_order():
    errors = []
    for h in (2e-3, 1e-3, 5e-4, 2.5e-4):
        nodes = wk.bedding_nodes(0.02, h)
        c = DELTA_STATIC - nodes**2 / (2 * R)
        f = K * float(wk.bedding_integral(jnp.asarray(c), nodes))
        errors.append(f / 118e3 - 1)
    errors = np.array(errors)
    assert np.all(errors < 0)  # linear interpolant of a concave profile under-estimates
    order = np.log2(errors[:-1] / errors[1:])
    assert np.all((order > 1.8) & (order < 2.3)), order
    assert abs(errors[1]) < TOL_STATIC_1MM


def test_smooth_wheel_exact_circle_reproduces_hertz():
    smooth = Flat.none()
    f = float(wk.force(smooth, DELTA_STATIC, 0.0, MAT, R))
    assert abs(f / 118e3 - 1) < TOL_STATIC_1MM
    assert f / 118e3 - 1 == pytest.approx(-2.59e-3, abs=0.05e-3)  # measured value
    f_fine = float(wk.force(smooth, DELTA_STATIC, 0.0, MAT, R, element=1e-4))
    assert abs(f_fine / 118e3 - 1) < 1e-4
    # over a range of approaches the deficit follows h^2 / (8 R delta) (interpolation) plus
    # 0.15 delta / R (the circle lies x^4 / (8 R^3) above its parabola)
    deltas = np.linspace(5e-5, 1e-3, 40)
    rel = np.asarray(wk.force(smooth, deltas, 0.0, MAT, R)) / np.asarray(
        hertz.force(deltas, MAT, R)
    ) - 1
    predicted = 1e-6 / (8 * R * deltas) + 0.15 * deltas / R
    np.testing.assert_allclose(-rel, predicted, rtol=0.05)


def test_flat_far_from_contact_is_hertz():
    smooth = Flat.none()
    for flat in (Flat.new(2e-3), Flat.rounded_relative(1e-3)):
        for s in (-0.2, 0.2):
            f = wk.force(flat, DELTA_STATIC, s, MAT, R)
            smooth_f = float(wk.force(smooth, DELTA_STATIC, s, MAT, R))
            assert float(f) == pytest.approx(smooth_f, rel=1e-13)  # windows differ in length
            assert abs(float(f) / 118e3 - 1) < TOL_STATIC_1MM


def test_rounded_flat_at_centre_matches_quadrature():
    depth = 1e-3
    flat = Flat.rounded_relative(depth)
    length = float(flat.length)

    def z_rf(x):
        return 0.5 * depth * (1 + math.cos(2 * math.pi * x / length)) if abs(x) <= length / 2 else 0

    delta = depth + 0.1e-3
    ref = _quad_force(z_rf, delta, 0.05)
    assert float(wk.force(flat, delta, 0.0, MAT, R)) / ref - 1 == pytest.approx(0, abs=1.5e-3)
    fine = float(wk.force(flat, delta, 0.0, MAT, R, element=5e-5))
    assert fine / ref - 1 == pytest.approx(0, abs=1e-5)


def test_new_flat_off_centre_matches_quadrature():
    depth = 1e-3
    flat = Flat.new(depth)

    def z_nf(x):  # exact chord
        return max(0.0, R - (R - depth) / math.cos(x / R)) if abs(x) < 0.1 else 0.0

    s, delta = 12e-3, 0.6e-3
    ref = _quad_force(lambda x: z_nf(x + s), delta, 0.05)
    assert float(wk.force(flat, delta, s, MAT, R)) / ref - 1 == pytest.approx(0, abs=2e-3)
    fine = float(wk.force(flat, delta, s, MAT, R, element=5e-5))
    assert fine / ref - 1 == pytest.approx(0, abs=2e-5)


@pytest.mark.parametrize("flat", [Flat.new(1e-3), Flat.rounded_relative(1e-3)],
                         ids=["new", "rounded"])
def test_force_continuous_in_s_through_flat_edges(flat):
    # A jump would keep the largest step-to-step change fixed as the step is halved.
    nodes = wk.bedding_nodes(wk.default_half_window(flat, R))
    f = jax.jit(lambda s: wk.force_at_nodes(flat, 0.4e-3, s, MAT, R, nodes))
    max_change = []
    for step in (1e-5, 5e-6, 2.5e-6):
        s = np.arange(-0.08, 0.08, step)
        values = np.asarray(f(s))
        assert values.min() < 0.5 * values.max()  # the flat passes the contact
        max_change.append(np.max(np.abs(np.diff(values))))
    ratios = np.array(max_change[:-1]) / np.array(max_change[1:])
    assert np.all(ratios > 1.8), ratios


def test_onset_is_where_contact_begins():
    depth = 1e-3
    flat = Flat.rounded_relative(depth)
    assert float(wk.onset(flat, 0.0)) == pytest.approx(depth, rel=1e-14)
    assert float(wk.onset(Flat.none(), 0.3)) == 0.0
    for s in (-0.03, 0.0, 0.021):
        d0 = float(wk.onset(flat, s))
        assert float(wk.force(flat, d0, s, MAT, R)) < 1e-9  # round-off of c at one node
        assert float(wk.force(flat, d0 - 1e-12, s, MAT, R)) == 0.0
        assert float(wk.force(flat, d0 + 1e-8, s, MAT, R)) > 1e-3


def test_window_covers_default_max_approach():
    flat = Flat.new(2e-3)
    nodes = wk.bedding_nodes(wk.default_half_window(flat, R))
    assert float(wk.window_max_approach(nodes, R)) >= 2e-3 + wk.DEFAULT_APPROACH_MARGIN
    # and the window really holds the contact: a wider one gives the same force
    wide = wk.bedding_nodes(0.1)
    for s in (0.0, 0.02, 0.031):
        a = wk.force_at_nodes(flat, 2.9e-3, s, MAT, R, nodes)
        b = wk.force_at_nodes(flat, 2.9e-3, s, MAT, R, wide)
        assert float(a) == pytest.approx(float(b), rel=1e-12)


def test_jit_vmap_batched_equals_looped():
    flat = Flat.rounded_relative(1e-3)
    nodes = wk.bedding_nodes(wk.default_half_window(flat, R))
    rng = np.random.default_rng(0)
    approach = rng.uniform(-1e-4, 1.5e-3, 32)
    s = rng.uniform(-0.06, 0.06, 32)

    def one(a, x):
        return wk.force_at_nodes(flat, a, x, MAT, R, nodes)

    batched = jax.jit(jax.vmap(one))(approach, s)
    looped = np.array([float(wk.force(flat, a, x, MAT, R)) for a, x in zip(approach, s,
                                                                             strict=True)])
    np.testing.assert_allclose(batched, looped, rtol=1e-13, atol=1e-9)
    # broadcasting inside force() gives the same numbers
    np.testing.assert_allclose(wk.force(flat, approach, s, MAT, R), looped, rtol=1e-13,
                               atol=1e-9)
    # vmap over flats (depth and length as batched leaves)
    depths = jnp.array([0.5e-3, 1e-3, 2e-3])
    lengths = 1.76 * jnp.sqrt(8 * R * depths)
    per_flat = jax.vmap(
        lambda d, ell: wk.force_at_nodes(Flat("rounded", d, ell), 1.2e-3, 0.01, MAT, R, nodes)
    )(depths, lengths)
    for i in range(3):
        single = Flat("rounded", float(depths[i]), float(lengths[i]))
        assert float(per_flat[i]) == pytest.approx(
            float(wk.force_at_nodes(single, 1.2e-3, 0.01, MAT, R, nodes)), rel=1e-13)


def _central(f, x, eps):
    return (f(x + eps) - f(x - eps)) / (2 * eps)


@pytest.mark.parametrize("kind", ["new", "rounded"])
def test_gradients_match_finite_differences(kind):
    depth, length = 1e-3, 1.76 * math.sqrt(8 * R * 1e-3)
    nodes = wk.bedding_nodes(0.06)

    def f(approach, s, d, ell):
        return wk.force_at_nodes(Flat(kind, d, ell), approach, s, MAT, R, nodes)

    args = (0.7e-3, 0.013, depth, length)
    grads = jax.grad(f, argnums=(0, 1, 2, 3))(*args)
    steps = (1e-9, 1e-8, 1e-9, 1e-8)
    for i, (g, eps) in enumerate(zip(grads, steps, strict=True)):
        def fi(x, i=i):
            a = list(args)
            a[i] = x
            return float(f(*a))

        fd = _central(fi, args[i], eps)
        if kind == "new" and i == 3:  # a new flat's geometry does not use the length
            assert float(g) == 0.0 and abs(fd) < 1e-3
            continue
        assert abs(fd) > 1e3  # the derivative is not trivially zero
        assert float(g) == pytest.approx(fd, rel=2e-6), (kind, i)


def test_gradient_wrt_measured_profile_values():
    x = np.linspace(-0.03, 0.03, 61)
    z = 0.8e-3 * np.cos(np.pi * x / 0.06) ** 2
    nodes = wk.bedding_nodes(0.05)

    def f(zz):
        return wk.force_at_nodes(Flat("profile", 0.8e-3, 0.06, R, x, zz), 0.9e-3, 0.004, MAT,
                                 R, nodes)

    g = np.asarray(jax.grad(f)(jnp.asarray(z)))
    assert np.all(g <= 0) and g.min() < 0  # removing material reduces the force
    for j in (25, 30, 33):
        dz = np.zeros_like(z)
        dz[j] = 1e-9
        fd = (float(f(z + dz)) - float(f(z - dz))) / 2e-9
        assert g[j] == pytest.approx(fd, rel=1e-5)


def test_newton_helper_and_no_contact_gradients():
    flat = Flat.new(1e-3)
    nodes = wk.bedding_nodes(wk.default_half_window(flat, R))
    f, k = wk.force_and_stiffness_at_nodes(flat, 0.8e-3, 0.01, MAT, R, nodes)
    assert float(f) == float(wk.force_at_nodes(flat, 0.8e-3, 0.01, MAT, R, nodes))
    g = jax.grad(wk.force_at_nodes, argnums=1)(flat, 0.8e-3, 0.01, MAT, R, nodes)
    assert float(k) == pytest.approx(float(g), rel=1e-13) and float(k) > 0
    # the split used by the time loop: gap once per step, then F(delta) from the gap
    gap = wk.gap_at_nodes(flat, 0.01, R, nodes)
    f2, k2 = wk.force_and_stiffness_from_gap(gap, 0.8e-3, MAT, nodes)
    assert float(f2) == pytest.approx(float(f), rel=1e-14)
    assert float(k2) == pytest.approx(float(k), rel=1e-14)
    # Newton on F(delta) = 118 kN (F is convex in delta) converges from just above the onset
    delta = wk.onset_at_nodes(flat, 0.01, R, nodes) + 1e-4
    for _ in range(30):
        f_n, k_n = wk.force_and_stiffness_from_gap(gap, delta, MAT, nodes)
        delta = delta - (f_n - 118e3) / k_n
    assert abs(float(wk.force_from_gap(gap, delta, MAT, nodes)) - 118e3) < 1e-6
    # no contact: zero force, zero and finite gradients (also w.r.t. the flat)
    for approach in (0.0, -1e-4):
        grads = jax.grad(
            lambda a, s, d: wk.force_at_nodes(Flat("new", d, 0.06), a, s, MAT, R, nodes),
            argnums=(0, 1, 2),
        )(approach, 0.0, 1e-3)
        assert all(float(v) == 0.0 for v in grads)
    # grad through the validated wrapper with a traced depth
    g_d = jax.grad(lambda d: wk.force(Flat("rounded", d, 0.1), 1.1e-3, 0.0, MAT, R))(1e-3)
    assert np.isfinite(float(g_d)) and float(g_d) < 0


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"element": 0.0}, "element"),
        ({"element": -1e-3}, "element"),
        ({"approach": float("nan")}, "approach"),
        ({"s": float("inf")}, "s"),
        ({"wheel_radius": 0.0}, "wheel_radius"),
        ({"wheel_radius": -0.45}, "wheel_radius"),
        ({"half_window": 0.0}, "half_window"),
        ({"half_window": 0.3}, "half_window"),
    ],
)
def test_bad_input_raises(kwargs, name):
    args = {"flat": Flat.new(1e-3), "approach": 1e-4, "s": 0.0, "material": MAT,
            "wheel_radius": R, **kwargs}
    with pytest.raises(ValueError, match=rf"^{name} must be .*got"):
        wk.force(**args)

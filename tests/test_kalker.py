"""Tests of the 3D Kalker contact solver (wfjax.contact.kalker) against Hertz theory."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import ellipe, ellipk

import wfjax as wf
from wfjax.contact import geometry3d, influence, kalker

MAT = wf.Material()
ESTAR = 210e9 / (2 * (1 - 0.3**2))
F_STATIC = 118e3
R = 0.45


def hertz_sphere(force, radius):
    """Circular Hertz (formulas.md): delta, a, p0."""
    c_h = 2 / 3 * 210e9 / (1 - 0.3**2) * math.sqrt(radius)
    delta = (force / c_h) ** (2 / 3)
    a = math.sqrt(radius * delta)
    return delta, a, 3 * force / (2 * math.pi * a * a)


def smooth_gap(h, half, rail_radius=R):
    n = int(round(half / h))
    x = np.arange(-n, n + 1) * h
    return geometry3d.gap_3d(wf.Flat.none(), 0.0, x, x, R, rail_radius), x


def moments(p, x, y, h):
    """Semi-axes from second moments of the pressure: <x^2> = a^2/5 (+ h^2/12 per element)."""
    p = np.asarray(p)
    w = p.sum()
    ax = math.sqrt(5 * ((p.sum(1) * x**2).sum() / w + h * h / 12))
    ay = math.sqrt(5 * ((p.sum(0) * y**2).sum() / w + h * h / 12))
    return ax, ay


# --------------------------------------------------------------------------- influence


def love_reference(x, y, a, b):
    """Love's formula exactly as in formulas.md (logs), per unit p, times pi E*."""

    def f(u, v):
        r = math.hypot(u, v)
        t1 = u * math.log(v + r) if u != 0 else 0.0
        t2 = v * math.log(u + r) if v != 0 else 0.0
        return t1 + t2

    return f(x + a, y + b) - f(x + a, y - b) - f(x - a, y + b) + f(x - a, y - b)


def test_influence_kernel_matches_love_formula():
    dx, dy = 1e-3, 2e-3
    k = np.asarray(influence.influence_kernel(4, 3, dx, dy, MAT))
    for i, j in [(0, 0), (1, 0), (0, 2), (3, 2), (2, 1)]:
        ref = love_reference(i * dx, j * dy, dx / 2, dy / 2) / (math.pi * ESTAR)
        assert k[i + 3, j + 2] == pytest.approx(ref, rel=1e-10)
        assert k[3 - i, 2 - j] == pytest.approx(ref, rel=1e-10)  # symmetric
    # centre of a square element: 8 a asinh(1) / (pi E*) (Johnson Sec. 3.2)
    kc = np.asarray(influence.influence_kernel(1, 1, 2e-3, 2e-3, MAT))[0, 0]
    assert kc == pytest.approx(8e-3 * math.asinh(1) / (math.pi * ESTAR), rel=1e-12)


def test_dense_and_fft_operators_agree():
    nx, ny, dx, dy = 11, 7, 1e-3, 1.5e-3
    p = np.random.default_rng(0).uniform(0, 1e9, (nx, ny))
    u_fft = influence.make_operator(nx, ny, dx, dy, MAT)(jnp.asarray(p))
    u_dense = influence.make_operator(nx, ny, dx, dy, MAT, method="dense")(jnp.asarray(p))
    c = np.asarray(influence.dense_matrix(nx, ny, dx, dy, MAT))
    assert np.allclose(c, c.T, rtol=0, atol=1e-14 * np.abs(c).max())
    u_mat = (c @ p.ravel()).reshape(nx, ny)
    scale = np.abs(u_mat).max()
    assert np.abs(np.asarray(u_fft) - u_mat).max() < 1e-13 * scale
    assert np.abs(np.asarray(u_dense) - u_mat).max() < 1e-13 * scale


# --------------------------------------------------------------------------- Hertz


def test_smooth_wheel_matches_hertz_at_half_mm():
    h = 0.5e-3
    gap, x = smooth_gap(h, 11e-3)
    d_h, a_h, p0_h = hertz_sphere(F_STATIC, R)
    assert d_h == pytest.approx(0.1093e-3, rel=2e-3) and a_h == pytest.approx(7.01e-3, rel=2e-3)
    res = kalker.solve(gap, h, h, MAT, force=F_STATIC)
    assert bool(res.diagnostics.converged)
    assert float(res.approach) == pytest.approx(d_h, rel=0.01)
    res_a = kalker.solve(gap, h, h, MAT, approach=d_h)
    assert float(res_a.force) == pytest.approx(F_STATIC, rel=0.01)
    ax, ay = moments(res.pressure, x, x, h)
    assert ax == pytest.approx(a_h, rel=0.01) and ay == pytest.approx(a_h, rel=0.01)
    assert float(res.pressure.max()) == pytest.approx(p0_h, rel=0.02)
    # stiffness = dF/d delta = 1.5 F / delta for Hertz
    assert float(res.stiffness) == pytest.approx(1.5 * F_STATIC / d_h, rel=0.01)


@pytest.mark.slow  # the default run must stay under 10 min (2 cores)
def test_refinement_converges_towards_hertz():
    d_h, a_h, p0_h = hertz_sphere(F_STATIC, R)
    hs = [1e-3, 0.5e-3, 0.25e-3]
    e_p, e_a, e_d = [], [], []
    for h in hs:
        gap, _ = smooth_gap(h, 10e-3)
        res = kalker.solve(gap, h, h, MAT, force=F_STATIC)
        e_d.append(abs(float(res.approach) / d_h - 1))
        e_p.append(abs(float(res.pressure.max()) / p0_h - 1))
        e_a.append(abs(float(res.contact.sum()) * h * h / (math.pi * a_h**2) - 1))
    for e in (e_p, e_a, e_d):
        assert e[0] > e[1] > e[2]
    order_p = math.log(e_p[0] / e_p[2]) / math.log(hs[0] / hs[2])
    order_a = math.log(e_a[0] / e_a[2]) / math.log(hs[0] / hs[2])
    assert order_p > 1.5  # observed ~2: element-averaged pressure at the centre
    assert order_a > 0.7  # observed ~1: the boundary of a staircase area
    assert e_p[2] < 2e-3 and e_a[2] < 0.02


def test_complete_elliptic_integrals_equal_scipy():
    """The AGM's K(m) and E(m) (no scipy.special import on a warm sweep's path) against
    scipy's, from a circle to a needle-thin ellipse (m -> 1)."""
    ms = np.concatenate([np.linspace(0.0, 0.999, 200), 1 - np.geomspace(1e-3, 1e-15, 25)])
    got = np.array([geometry3d.complete_elliptic(float(m)) for m in ms])
    np.testing.assert_allclose(got[:, 0], ellipk(ms), rtol=1e-14)
    np.testing.assert_allclose(got[:, 1], ellipe(ms), rtol=1e-14)


def test_elliptic_hertz_formulas():
    # circular limit and the ratio relation (independent of the implementation's root find)
    ax, ay, d, p0 = geometry3d.elliptic_hertz(F_STATIC, R, R * (1 + 1e-9), MAT)
    d_h, a_h, p0_h = hertz_sphere(F_STATIC, R)
    assert ax == pytest.approx(a_h, rel=1e-6) and d == pytest.approx(d_h, rel=1e-6)
    ax, ay, d, p0 = geometry3d.elliptic_hertz(F_STATIC, R, 0.30, MAT)
    m = 1 - (ay / ax) ** 2
    k, e = ellipk(m), ellipe(m)
    assert (e / (1 - m) - k) / (k - e) == pytest.approx(R / 0.30, rel=1e-9)
    assert p0 == pytest.approx(3 * F_STATIC / (2 * math.pi * ax * ay), rel=1e-12)


def test_elliptic_contact_rail_radius_030():
    h = 0.5e-3
    gap, x = smooth_gap(h, 11e-3, rail_radius=0.30)
    ax_h, ay_h, d_h, _ = geometry3d.elliptic_hertz(F_STATIC, R, 0.30, MAT)
    res = kalker.solve(gap, h, h, MAT, force=F_STATIC)
    assert float(res.approach) == pytest.approx(d_h, rel=0.01)
    ax, ay = moments(res.pressure, x, x, h)
    assert ax / ay == pytest.approx(ax_h / ay_h, rel=0.01)
    assert ax_h / ay_h > 1.15  # the test can tell ellipse from circle


# --------------------------------------------------------------------------- solution


def test_complementarity_and_modes_agree():
    h = 1e-3
    gap, _ = smooth_gap(h, 12e-3, rail_radius=0.30)
    res_f = kalker.solve(gap, h, h, MAT, force=F_STATIC)
    res_a = kalker.solve(gap, h, h, MAT, approach=res_f.approach)
    for res in (res_f, res_a):
        assert float(res.diagnostics.residual) < 1e-7
        p = np.asarray(res.pressure)
        c = np.asarray(influence.dense_matrix(*gap.shape, h, h, MAT))
        d = np.asarray(gap) - float(res.approach) + (c @ p.ravel()).reshape(p.shape)
        assert p.min() >= 0
        assert d.min() > -1e-9 * float(res.approach)
        assert np.abs(p * d).max() < 1e-8 * p.max() * float(res.approach)
        assert np.array_equal(np.asarray(res.contact), p > 0)
    assert float(res_a.force) == pytest.approx(F_STATIC, rel=1e-8)
    assert np.allclose(res_a.pressure, res_f.pressure, rtol=0, atol=1e-7 * res_f.pressure.max())


def test_dense_method_solves_the_same():
    h = 1e-3
    gap, _ = smooth_gap(h, 9e-3)
    r1 = kalker.solve(gap, h, h, MAT, force=80e3)
    r2 = kalker.solve(gap, h, h, MAT, force=80e3, method="dense")
    assert float(r1.approach) == pytest.approx(float(r2.approach), rel=1e-9)


def test_padding_independence():
    h = 1e-3
    small, _ = smooth_gap(h, 10e-3)
    large, _ = smooth_gap(h, 16e-3)
    r1 = kalker.solve(small, h, h, MAT, approach=0.1e-3)
    r2 = kalker.solve(large, h, h, MAT, approach=0.1e-3)
    assert float(r1.force) == pytest.approx(float(r2.force), rel=1e-9)
    assert np.allclose(r1.pressure, np.asarray(r2.pressure)[6:-6, 6:-6], rtol=0,
                       atol=1e-8 * float(r1.pressure.max()))


def test_warm_start_is_faster_and_identical():
    h = 1e-3
    gap, _ = smooth_gap(h, 12e-3)
    cold = kalker.solve(gap, h, h, MAT, approach=0.11e-3)
    prev = kalker.solve(gap, h, h, MAT, approach=0.105e-3)
    warm = kalker.solve(gap, h, h, MAT, approach=0.11e-3, p_init=prev.pressure)
    # With the preconditioned CG each solve takes few CG iterations; the warm start saves
    # active-set iterations (each one an operator application and a CG solve).
    assert int(warm.diagnostics.iterations) < int(cold.diagnostics.iterations)
    assert int(warm.diagnostics.cg_iterations) <= int(cold.diagnostics.cg_iterations)
    assert float(warm.force) == pytest.approx(float(cold.force), rel=1e-9)


def test_preconditioned_cg_same_solution_fewer_iterations():
    """The FFT preconditioner changes the path, not the solution: same force and pressure as
    plain CG, and several times fewer CG iterations on a 0.5 mm grid of a flat's contact."""
    h = 0.5e-3
    flat = wf.Flat.rounded(0.9e-3, 0.1)
    x = np.arange(-60, 61) * h
    y = np.arange(-30, 31) * h
    gap = geometry3d.gap_3d(flat, -0.03, x, y, 0.45, 0.30)
    out = {}
    for precondition in (False, True):
        cfg = kalker._Config(len(x), len(y), h, h, "fft", 1e-10, 1000, precondition)
        out[precondition] = kalker._solve_impl(cfg, gap, MAT, None, 118e3, None, 50, True,
                                               True)[0]
    plain, prec = out[False], out[True]
    assert bool(plain.diagnostics.converged) and bool(prec.diagnostics.converged)
    assert float(prec.approach) == pytest.approx(float(plain.approach), rel=1e-9)
    assert float(prec.stiffness) == pytest.approx(float(plain.stiffness), rel=1e-8)
    np.testing.assert_allclose(prec.pressure, plain.pressure, rtol=0,
                               atol=1e-7 * float(plain.pressure.max()))
    assert 2 * int(prec.diagnostics.cg_iterations) < int(plain.diagnostics.cg_iterations)


def test_flat_far_away_is_smooth_wheel():
    h = 1e-3
    x = np.arange(-12, 13) * h
    flat = wf.Flat.rounded(0.9e-3, 0.1)
    g_far = geometry3d.gap_3d(flat, -0.2, x, x, R, R)
    g_smooth = geometry3d.gap_3d(wf.Flat.none(), 0.0, x, x, R, R)
    assert np.array_equal(np.asarray(g_far), np.asarray(g_smooth))
    g_on = geometry3d.gap_3d(flat, 0.0, x, x, R, R)
    assert float(g_on[12, 12]) == pytest.approx(0.9e-3, rel=1e-12)  # flat centre: depth d
    res = kalker.solve(g_far, h, h, MAT, force=F_STATIC)
    assert float(res.approach) == pytest.approx(hertz_sphere(F_STATIC, R)[0], rel=0.01)


def test_force_continuous_in_s_through_flat_edge():
    h = 1e-3
    x = np.arange(-30, 31) * h
    flat = wf.Flat.rounded(0.9e-3, 0.1)

    def force(s):
        g = geometry3d.gap_3d(flat, s, x, x[10:-10], R, R)
        return float(kalker.solve(g, h, h, MAT, approach=0.11e-3).force)

    s_values = -0.05 - 0.012 + np.arange(0, 24) * 1e-3  # contact edge passes the flat edge
    forces = np.array([force(s) for s in s_values])
    assert forces[0] == pytest.approx(forces[1], rel=1e-12)  # flat not yet in contact
    assert forces[-1] < 0.9 * forces[0]  # the flat unloads the contact
    # continuity: where the force changes fastest, a 4x smaller step gives a ~4x smaller change
    i = int(np.argmax(np.abs(np.diff(forces))))
    coarse = abs(forces[i + 1] - forces[i])
    fine = abs(force(s_values[i] + 0.25e-3) - forces[i])
    assert fine < 0.4 * coarse


# --------------------------------------------------------------------------- JAX


def _flat_gap(depth, s, h):
    """Gap [m] of a rounded flat (l = 100 mm) on a 41 x 25 grid of h-sized elements."""
    x = np.arange(-20, 21) * h
    y = np.arange(-12, 13) * h
    return geometry3d.gap_3d(wf.Flat("rounded", depth=depth, length=0.1), s, x, y, R, 0.30)


def _flat_force(depth, s, delta, h=1e-3):
    return kalker.solve(_flat_gap(depth, s, h), h, h, MAT, approach=delta, stiffness=False).force


def _flat_approach(depth, s, force, h=1e-3):
    return kalker.solve(_flat_gap(depth, s, h), h, h, MAT, force=force, stiffness=False).approach


@pytest.mark.parametrize("fun,args,steps", [
    (_flat_force, (0.9e-3, -0.045, 0.12e-3), (1e-8, 1e-6, 1e-9)),
    (_flat_approach, (0.9e-3, -0.045, 100e3), (1e-8, 1e-6, 1.0)),
])
def test_grad_matches_finite_differences(fun, args, steps):
    grads = jax.grad(fun, argnums=(0, 1, 2))(*args)
    for i, eps in enumerate(steps):
        up, dn = list(args), list(args)
        up[i] += eps
        dn[i] -= eps
        fd = (float(fun(*up)) - float(fun(*dn))) / (2 * eps)
        assert float(grads[i]) == pytest.approx(fd, rel=2e-5)
        assert abs(fd) > 0


def test_stiffness_is_derivative_of_force():
    h = 1e-3
    gap, _ = smooth_gap(h, 12e-3, rail_radius=0.3)
    res = kalker.solve(gap, h, h, MAT, approach=0.1e-3)
    dfd = jax.grad(lambda d: kalker.solve(gap, h, h, MAT, approach=d).force)(0.1e-3)
    assert float(res.stiffness) == pytest.approx(float(dfd), rel=1e-7)


def test_jit_and_vmap_batched_equals_looped():
    h = 1e-3
    x = np.arange(-15, 16) * h
    flat = wf.Flat.rounded(0.9e-3, 0.1)

    @jax.jit
    def solve_at(s, delta):
        g = geometry3d.gap_3d(flat, s, x, x, R, R)
        r = kalker.solve(g, h, h, MAT, approach=delta)
        return r.force, r.stiffness, r.diagnostics.converged

    s = jnp.array([-0.06, -0.05, -0.04, 0.0])
    d = jnp.array([0.1e-3, 0.12e-3, 0.3e-3, 1.0e-3])
    fb, kb, okb = jax.vmap(solve_at)(s, d)
    for i in range(4):
        fl, kl, _ = solve_at(s[i], d[i])
        assert float(fb[i]) == pytest.approx(float(fl), rel=1e-9)
        assert float(kb[i]) == pytest.approx(float(kl), rel=1e-7)
    assert bool(jnp.all(okb))


def test_solve_inside_scan_with_warm_start():
    h = 1e-3
    x = np.arange(-15, 16) * h
    g = geometry3d.gap_3d(wf.Flat.none(), 0.0, x, x, R, R)

    def step(p, delta):
        r = kalker.solve(g, h, h, MAT, approach=delta, p_init=p)
        return r.pressure, r.force

    _, forces = jax.lax.scan(step, jnp.zeros_like(g), jnp.linspace(0.05e-3, 0.12e-3, 5))
    ref = kalker.solve(g, h, h, MAT, approach=0.12e-3).force
    assert float(forces[-1]) == pytest.approx(float(ref), rel=1e-9)


# --------------------------------------------------------------------------- bad input


def test_bad_input_raises():
    h = 1e-3
    gap, _ = smooth_gap(h, 10e-3)
    with pytest.raises(ValueError, match="dx"):
        kalker.solve(gap, 0.0, h, MAT, approach=1e-4)
    with pytest.raises(ValueError, match="dy"):
        kalker.solve(gap, h, -1e-3, MAT, approach=1e-4)
    with pytest.raises(ValueError, match="NaN"):
        kalker.solve(gap.at[3, 3].set(jnp.nan), h, h, MAT, approach=1e-4)
    with pytest.raises(ValueError, match="exactly one"):
        kalker.solve(gap, h, h, MAT)
    with pytest.raises(ValueError, match="exactly one"):
        kalker.solve(gap, h, h, MAT, approach=1e-4, force=1e5)
    coarse, _ = smooth_gap(3e-3, 30e-3)
    with pytest.raises(ValueError, match="too coarse"):
        kalker.solve(coarse, 3e-3, 3e-3, MAT, force=F_STATIC)
    tiny, _ = smooth_gap(h, 4e-3)
    with pytest.raises(ValueError, match="too small"):
        kalker.solve(tiny, h, h, MAT, force=F_STATIC)
    with pytest.raises(ValueError, match="element_size"):
        geometry3d.contact_grid(wf.Flat.none(), R, R, MAT, element_size=5e-3)


def test_non_convergence_reported_not_nan():
    h = 1e-3
    gap, _ = smooth_gap(h, 12e-3)
    for kw in (dict(approach=0.1e-3), dict(force=F_STATIC)):
        res = kalker.solve(gap, h, h, MAT, max_iter=1, validate=False, **kw)
        assert not bool(res.diagnostics.converged)
        assert np.all(np.isfinite(np.asarray(res.pressure)))
        assert np.isfinite(float(res.force)) and np.isfinite(float(res.approach))
    res = kalker.solve(gap, h, h, MAT, approach=0.1e-3, cg_max_iter=2, validate=False)
    assert not bool(res.diagnostics.converged)


def test_contact_grid_contains_contact():
    flat = wf.Flat.new(0.9e-3)
    x, y = geometry3d.contact_grid(flat, R, 0.30, MAT, max_force=300e3, element_size=1.2e-3)
    assert len(x) % 2 == 1 and x[len(x) // 2] == 0.0
    for s in (0.0, -0.02):
        g = geometry3d.gap_3d(flat, s, x, y, R, 0.30)
        res = kalker.solve(g, 1.2e-3, 1.2e-3, MAT, force=300e3)  # validates containment
        assert bool(res.diagnostics.converged)

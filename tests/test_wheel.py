"""Tests of the 2-DOF wheel model against closed forms and direct convolution."""

import numpy as np
import pytest
import scipy.linalg

import wfjax
from wfjax.model import wheel as W


def closed_form_receptance(p: wfjax.Wheel, f):
    """H11 of the 2-DOF chain m_W -(k_W, c_W)- M_W -(k_S, c_S)- ground, written out by hand."""
    w = 2 * np.pi * np.asarray(f)
    z_w = p.contact_stiffness + 1j * w * p.contact_damping
    z_s = p.suspension_stiffness + 1j * w * p.suspension_damping
    d11 = z_w - w**2 * p.small_mass
    d22 = z_w + z_s - w**2 * p.wheelset_mass
    return d22 / (d11 * d22 - z_w**2)


def test_receptance_matches_closed_form():
    p = wfjax.Wheel()
    f = np.geomspace(1.0, 20e3, 300)
    h = W.receptance(p, f)
    np.testing.assert_allclose(h, closed_form_receptance(p, f), rtol=1e-10)
    # static limit: springs in series
    np.testing.assert_allclose(W.receptance(p, [0.0])[0].real,
                               1 / p.suspension_stiffness + 1 / p.contact_stiffness, rtol=1e-12)


def test_modal_receptance_matches_direct():
    p = wfjax.Wheel()
    mod = W.modal_model(p)
    f = np.geomspace(1.0, 20e3, 200)
    s = 2j * np.pi * f[:, None]
    lam, res = np.asarray(mod.poles), np.asarray(mod.residues)
    # Re-part expansion: (r/2)/(s-lam) + (conj r/2)/(s - conj lam) for pair representatives
    h = (0.5 * res / (s - lam) + 0.5 * np.conj(res) / (s - np.conj(lam))).sum(axis=1)
    np.testing.assert_allclose(h, closed_form_receptance(p, f), rtol=1e-9)


def test_static_displacement():
    p = wfjax.Wheel(preload=100e3)
    assert W.static_displacement(p) == pytest.approx(100e3 / 1.12e6 + 100e3 / 2.4e9, rel=1e-12)


def test_greens_function_is_inverse_fft_of_receptance():
    p = wfjax.Wheel()
    fs, n = 200e3, 2**18  # 1.3 s window: the 6 Hz suspension mode has decayed by then
    dt = 1 / fs
    f = np.fft.rfftfreq(n, dt)
    h_ifft = np.fft.irfft(W.receptance(p, f), n) / dt
    t = np.arange(n) * dt
    g = np.asarray(W.greens_function(p, t))
    sel = slice(4, n // 2)  # skip the t = 0 discontinuity of the velocity (Gibbs)
    err = np.max(np.abs(g[sel] - h_ifft[sel])) / np.max(np.abs(g))
    assert err < 2e-3
    assert float(W.greens_function(p, -1e-3)) == 0.0


def _state_space_green(p, t):
    """h_W(t) = C expm(A t) B from the first-order system matrices (independent of modes)."""
    m, c, k = W.system_matrices(p)
    a = np.block([[np.zeros((2, 2)), np.eye(2)],
                  [-np.linalg.solve(m, k), -np.linalg.solve(m, c)]])
    b = np.concatenate([np.zeros(2), np.linalg.solve(m, [1.0, 0.0])])
    return np.array([scipy.linalg.expm(a * ti)[0] @ b for ti in np.atleast_1d(t)])


def test_greens_function_matches_matrix_exponential():
    p = wfjax.Wheel()
    t = np.array([1e-5, 1e-4, 1e-3, 0.01, 0.1])
    np.testing.assert_allclose(np.asarray(W.greens_function(p, t)), _state_space_green(p, t),
                               rtol=1e-9, atol=1e-12 * np.abs(_state_space_green(p, t)).max())


def test_exact_propagation_equals_direct_convolution():
    """State-space FOH update vs a direct convolution of the piecewise-linear force."""
    p = wfjax.Wheel()
    rng = np.random.default_rng(0)
    dt, n = 2.5e-5, 400
    force = rng.normal(size=n) * 1e4
    x_ss = np.asarray(W.response(W.modal_model(p), force, dt))

    # direct convolution: x_n = sum_k F_k int hat_k(tau) h(t_n - tau) dtau, Gauss-Legendre
    gl_x, gl_w = np.polynomial.legendre.leggauss(12)
    s = 0.5 * (gl_x + 1)  # nodes in [0, 1] of one step
    wq = 0.5 * gl_w
    lags = np.arange(n) * dt
    # kernel for lag j (t_n - t_k = j dt): rising half int_0^1 s h((j - 1 + 1 - s) dt) ...
    # hat_k on [t_{k-1}, t_k] rises (weight s), on [t_k, t_{k+1}] falls (weight 1 - s)
    tau_rise = (lags[:, None] + (1 - s)[None, :] * dt)  # t_n - tau for tau in [t_k - dt, t_k]
    tau_fall = (lags[:, None] - s[None, :] * dt)        # t_n - tau for tau in [t_k, t_k + dt]
    h_rise = _green_vals(p, tau_rise)
    h_fall = _green_vals(p, tau_fall)
    k_rise = dt * (h_rise * s * wq).sum(axis=1)         # lag j >= 0
    k_fall = dt * (h_fall * (1 - s) * wq).sum(axis=1)   # zero for lag 0 (tau > t_n)
    x_conv = np.zeros(n)
    for i in range(n):
        j = i - np.arange(i + 1)  # lags for k = 0..i
        kern = np.where(np.arange(i + 1) > 0, k_rise[j], 0.0) + np.where(j > 0, k_fall[j], 0.0)
        x_conv[i] = kern @ force[: i + 1]
    err = np.max(np.abs(x_ss - x_conv)) / np.max(np.abs(x_conv))
    assert err <= 1e-8


def _green_vals(p, t):
    t = np.asarray(t)
    return np.where(t > 0, np.asarray(W.greens_function(p, np.maximum(t, 0.0))), 0.0)


def test_discrete_step_coefficients_series_and_exact_agree():
    lam = np.array([-1.0 + 2.0j, -30.0 + 0.0j, -5e3 + 3e4j])
    for dt in (1e-7, 1e-3):  # tiny |z| uses the Taylor branch
        e, a_prev, a_now = (np.asarray(v) for v in W.discrete_step_coefficients(lam, dt))
        z = lam * dt
        # exact integrals by quadrature of exp(lam (dt - s)) (1 - s/dt) and ... s/dt
        gl_x, gl_w = np.polynomial.legendre.leggauss(20)
        s = 0.5 * dt * (gl_x + 1)
        w = 0.5 * dt * gl_w
        ker = np.exp(lam[:, None] * (dt - s[None, :]))
        np.testing.assert_allclose(a_now, (ker * s / dt * w).sum(1), rtol=1e-10)
        np.testing.assert_allclose(a_prev, (ker * (1 - s / dt) * w).sum(1), rtol=1e-10)
        np.testing.assert_allclose(e, np.exp(z), rtol=1e-14)


@pytest.mark.parametrize("field", ["small_mass", "contact_stiffness", "suspension_damping"])
def test_bad_input_names_the_parameter(field):
    with pytest.raises(ValueError, match=field):
        wfjax.Wheel(**{field: -1.0})
    with pytest.raises(ValueError, match=field):
        wfjax.Wheel(**{field: float("nan")})


def test_bad_frequencies():
    with pytest.raises(ValueError, match="freqs"):
        W.receptance(wfjax.Wheel(), [-1.0, 10.0])
    with pytest.raises(ValueError, match="freqs"):
        W.receptance(wfjax.Wheel(), [np.nan])

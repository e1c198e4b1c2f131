"""Tests of the discretely supported track model (wfjax.model.track) and the on-disk cache."""

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wfjax
from wfjax import _cache
from wfjax.model import greens as greens_mod
from wfjax.model import track as T

LS = 0.65
P = 118e3


def track(**kw) -> wfjax.Track:
    """The tests' FE track: absorbing ends on at least 24 bays (the default until 2026-12-06;
    the FE model's properties do not depend on the ends, and another mesh's end network would
    be fitted on first use; end networks: tests/test_end_network.py)."""
    return wfjax.Track(**{"n_bays": 24, "ends": "absorbing", **kw})


@pytest.fixture(scope="session")
def model(tmp_path_factory):
    return T.modal_model(track(), cache_dir=tmp_path_factory.mktemp("cache"))


# ---------------------------------------------------------------- static deflection
def boef_deflection(tr: wfjax.Track, force: float) -> float:
    ks = 1 / (1 / tr.pad_stiffness + 1 / tr.ballast_stiffness)
    k = ks / tr.sleeper_spacing
    beta = (k / (4 * tr.bending_stiffness)) ** 0.25
    return force * beta / (2 * k)


@pytest.mark.parametrize("x", [0.0, LS / 2])
def test_static_deflection_converged_and_near_boef(x):
    w = {n: T.static_deflection(track(elements_per_bay=n), P, x) for n in (2, 4, 8, 16)}
    for n in (4, 8):
        assert abs(w[2 * n] / w[n] - 1) < 5e-3
    w_boef = boef_deflection(track(), P)
    assert w_boef == pytest.approx(0.83e-3, rel=0.01)
    assert abs(w[8] / w_boef - 1) < 0.15
    assert w[8] > w_boef  # discrete supports: a little softer than the smeared foundation


@pytest.mark.parametrize("frac", [0.25, 0.5, 0.8125])
def test_point_load_inside_an_element_is_exact(frac):
    """A load inside an element of 8 per bay deflects as on a mesh with a node under the load
    (the Timoshenko element is exact there): the in-element correction closes the gap to
    1e-9 (without it the 8-element mesh is 1 % too stiff at mid-element), and the modal
    model's static point compliance (kept modes + residual table) agrees to 0.05 %."""
    coarse, fine = track(elements_per_bay=8), track(elements_per_bay=128)
    x = (2 + frac) * LS / 8  # inside element 2 of the coarse mesh, on a node of the fine one
    w_fine = T.static_deflection(fine, 1.0, x)
    assert T.static_deflection(coarse, 1.0, x) == pytest.approx(w_fine, rel=1e-9)
    from wfjax.model import beam as beam_mod
    bubble = float(beam_mod.element_interior_compliance(coarse, frac))
    assert bubble / w_fine > (0.005 if frac == 0.5 else 0.003)
    model = T.modal_model(coarse, use_cache=False)
    kept = np.real(np.sum(np.asarray(model.weights) * np.asarray(T.mode_shapes_at(model, x))**2
                          / -np.asarray(model.poles)))
    static = kept + float(T.residual_compliance_at(model, x))
    assert static == pytest.approx(w_fine, rel=5e-4)


def test_midspan_softer_than_above_sleeper():
    tr = track()
    assert T.static_deflection(tr, P, LS / 2) > T.static_deflection(tr, P, 0.0)


# ---------------------------------------------------------------- receptance features
def _peak(f, h, lo, hi):
    sel = (f >= lo) & (f <= hi)
    i = np.argmax(np.abs(h[sel]))
    return f[sel][i], np.abs(h[sel][i])


@pytest.mark.parametrize("epb", [8, 16])
def test_receptance_features(epb):
    tr = track(elements_per_bay=epb)
    f = np.concatenate([np.arange(50.0, 500.0, 2.0), np.arange(700.0, 1200.0, 5.0)])
    h0 = T.receptance(tr, f, 0.0)
    hm = T.receptance(tr, f, LS / 2)
    # full-track resonance (track mass on ballast) near 100 Hz
    f_track, _ = _peak(f, h0, 50, 200)
    assert 80 <= f_track <= 130
    # rail-on-pad resonance, a second peak between 200 and 500 Hz, well below the first
    f_pad, a_pad = _peak(f, h0, 200, 500)
    assert 230 <= f_pad <= 350 and f_pad - f_track > 100
    sel = (f > f_track) & (f < f_pad)
    assert np.min(np.abs(h0[sel])) < 0.98 * a_pad  # a real peak, not a shoulder
    # pinned-pinned resonance at midspan, absent above a sleeper
    f_pp, a_pp = _peak(f, hm, 700, 1200)
    assert 900 <= f_pp <= 1000
    i = np.argmin(np.abs(f - f_pp))
    assert a_pp > 5 * np.abs(h0[i])
    f0_max, _ = _peak(f, h0, 700, 1200)
    assert f0_max < 750  # above a sleeper the receptance falls through 0.7-1.2 kHz


def test_pinned_pinned_frequency_converges():
    f = np.arange(900.0, 980.0, 0.5)
    peaks = [_peak(f, T.receptance(track(elements_per_bay=n), f, LS / 2), 900, 980)[0]
             for n in (8, 16)]
    assert abs(peaks[1] - peaks[0]) <= 2.0


def test_reciprocity():
    tr = track()
    f = np.array([30.0, 150.0, 940.0, 2500.0])
    a, b = 0.1, 2.3
    np.testing.assert_allclose(T.receptance(tr, f, a, b), T.receptance(tr, f, b, a), rtol=1e-9)
    h = T.receptance(tr, f, 0.0, np.array([0.0, LS / 2]))
    assert h.shape == (4, 2)
    np.testing.assert_allclose(h[:, 0], T.receptance(tr, f, 0.0), rtol=1e-12)


# ---------------------------------------------------------------- modal model
def test_modal_model_layout(model):
    n = model.poles.shape[0]
    assert model.shapes.shape == (n, model.node_x.shape[0], 2)
    assert np.all(np.asarray(model.poles).imag >= 0)
    assert np.all(np.asarray(model.poles).real < 0)  # every mode damped
    assert set(np.unique(np.asarray(model.weights))) <= {1.0, 2.0}
    # the kept modes below the cut-off; above it at most the dampers' pseudo-modes (one per
    # pad and ballast damper: two per interior sleeper)
    above = np.abs(np.asarray(model.poles)) > 2 * np.pi * 20e3 * 1.01
    assert 0 < np.sum(above) <= 2 * (track().n_bays - 1)
    nx = np.asarray(model.node_x)
    half = track().n_bays // 2
    assert nx[0] == pytest.approx(-half * LS) and nx[-1] == pytest.approx(half * LS)
    assert np.any(np.isclose(nx, 0.0)) and np.allclose(np.asarray(model.shapes)[:, [0, -1]], 0)
    # residual: positive, periodic, small compared with the static compliance (with the
    # load's in-element deflection, about 1.1 % of it at mid-element)
    res = np.asarray(model.residual)
    # zero (to rounding) over the sleepers, whose rail nodes are dampers' DOFs: there the
    # dampers' pseudo-modes carry the truncated modes' whole static response
    tiny = 1e-9 * res.max()
    assert np.all(res > -tiny) and abs(res[0]) < tiny and abs(res[-1]) < tiny
    assert np.all(res[1:-1] > 0)
    assert res.max() < 0.015 * T.static_deflection(track(), 1.0)


@pytest.mark.parametrize("x", [0.0, 0.1, LS / 2, -2 * LS + 0.2])
def test_modal_receptance_matches_direct(model, x):
    f = np.geomspace(20.0, 3000.0, 60)
    hd = T.receptance(track(), f, x)
    hm = T.modal_receptance(model, f, x)
    assert np.max(np.abs(hm / hd - 1)) < 0.02


@pytest.mark.slow
def test_mode_shapes_at_jit_vmap_and_nodes(model):
    nx = np.asarray(model.node_x)
    i = np.argmin(np.abs(nx - 0.0)) + 3
    phi = jax.jit(T.mode_shapes_at)(model, jnp.asarray(nx[i]))
    np.testing.assert_allclose(phi, np.asarray(model.shapes)[:, i, 0], rtol=1e-10, atol=1e-14)
    xs = jnp.linspace(-0.3, 0.9, 7).reshape(7, 1)
    out = jax.vmap(lambda x: T.mode_shapes_at(model, x))(xs)
    assert out.shape == (7, 1, model.poles.shape[0])
    np.testing.assert_allclose(out[:, 0], T.mode_shapes_at(model, xs[:, 0]), rtol=1e-12)
    r = T.residual_compliance_at(model, jnp.array([0.1, 0.1 + LS, 0.1 - 3 * LS]))
    np.testing.assert_allclose(r, r[0], rtol=1e-12)


@pytest.mark.slow  # the default run must stay under 10 min (2 cores)
def test_greens_function_fourier_transform_is_point_receptance(model):
    """v -> 0: the Fourier transform of g(x0, t) (+ residual) is the direct point receptance.

    Quadrature: Riemann sum with the Euler-Maclaurin end correction dt^2/12 g'(0) (g jumps in
    slope at t = 0). The window must be long: rail modes near 2.6 kHz decay in ~0.25 s.
    """
    tr = track()
    dt = 1e-5
    f = np.geomspace(20.0, 3000.0, 40)
    for x0 in (0.0, LS / 2):
        g = greens_mod.moving_greens(tr, 1e-7, [x0], duration=1.5, dt=dt, model=model)
        gg = g.g[0]
        slope0 = (-3 * gg[0] + 4 * gg[1] - gg[2]) / (2 * dt)
        ft = (gg[None, :] * np.exp(-2j * np.pi * f[:, None] * g.t[None, :])).sum(1) * dt
        ft = ft + dt**2 / 12 * slope0 + g.residual[0]
        hd = T.receptance(tr, f, x0)
        # relative to |H| at its neighbouring grid points too, so that the deep antiresonance
        # at midspan near 2.64 kHz (|H| 30x below its neighbours) does not dominate
        a = np.abs(hd)
        scale = np.maximum(a, np.maximum(np.roll(a, 1), np.roll(a, -1)))
        assert np.max(np.abs(ft - hd) / scale) < 0.02
        assert np.median(np.abs(ft / hd - 1)) < 0.005


# The impulse responses g are compared on 8 elements per bay: an impulse excites every FE mode,
# and on the default 26 elements the full FE's modes far above the cut-off (the finer mesh
# has many) ring in the Newmark reference at 25 us sampling: 13 % apart, and neither 4x the
# substeps nor modes to 40 kHz close it (12 %). The time loop never sees an impulse (the
# contact force is smooth), and its own Newmark reference (tests/fe_reference.py) agrees.
# 70 bays: over the 0.1 s default window the ends' reflections of a 24-bay track keep the
# tail at 2.6 % of the peak (70 bays: under 2 %).
GREENS_TRACK = track(n_bays=70, elements_per_bay=8)


@pytest.fixture(scope="module")
def greens_model(tmp_path_factory):
    return T.modal_model(GREENS_TRACK, cache_dir=tmp_path_factory.mktemp("cache"))


@pytest.mark.slow
def test_moving_greens_two_ways_agree(greens_model):
    """Complex modes + static residual vs Newmark integration of the full FE model."""
    tr = GREENS_TRACK
    v = 100 / 3.6
    x0 = [0.0, 0.2]
    gm = greens_mod.moving_greens(tr, v, x0, duration=0.01, model=greens_model)
    gn = greens_mod.moving_greens_newmark(tr, v, x0, duration=0.01, substeps=40)
    for i in range(2):
        err = np.max(np.abs(gm.g[i] - gn.g[i])) / np.max(np.abs(gn.g[i]))
        assert err < 0.01
    # the excitation position matters (not a trivially periodic answer)
    assert np.max(np.abs(gm.g[0] - gm.g[1])) > 0.05 * np.max(np.abs(gm.g[0]))


@pytest.mark.slow
def test_moving_greens_default_grid_and_decay(greens_model):
    tr = GREENS_TRACK
    g = greens_mod.moving_greens(tr, 100 / 3.6, model=greens_model)
    assert g.g.shape == (27, g.t.size) and g.x0[0] == 0.0 and g.x0[-1] == pytest.approx(LS)
    assert g.t[-1] == pytest.approx(greens_mod.default_duration(tr))
    peak = np.abs(g.g).max(axis=1)
    tail = np.abs(g.g[:, -400:]).max(axis=1)  # last 10 ms of the window
    assert np.all(tail < 0.02 * peak)  # truncation leaves a small, slowly decaying ringing
    np.testing.assert_allclose(g.g[0], g.g[-1], rtol=0, atol=0.01 * peak.max())  # periodic


@pytest.mark.slow
def test_clamped_end_reflections_do_not_matter():
    """Same response on a 70-bay and a 140-bay track over the default 0.1 s window."""
    v = 30 / 3.6
    g70 = greens_mod.moving_greens_newmark(track(n_bays=70), v, [0.0], 0.1, substeps=2).g[0]
    g140 = greens_mod.moving_greens_newmark(track(n_bays=140), v, [0.0], 0.1, substeps=2).g[0]
    assert np.max(np.abs(g70 - g140)) < 5e-3 * np.max(np.abs(g70))


def test_discrete_state_space_matches_convolution(model):
    """Track modes at a fixed point, FOH state update vs direct convolution with g(t)."""
    x = 0.2
    dt, n = 2.5e-5, 300
    phi = T.mode_shapes_at(model, x)
    amp = np.asarray(model.weights * phi * phi)
    decay, a_prev, a_now = (np.asarray(c) for c in T.discrete_step_coefficients(model.poles, dt))
    force = np.random.default_rng(1).normal(size=n)
    q = np.zeros(amp.size, complex)
    x_ss = np.zeros(n)
    for i in range(1, n):
        q = decay * q + a_prev * force[i - 1] + a_now * force[i]
        x_ss[i] = np.real(amp @ q)
    # convolution of the piecewise-linear force with h(t) = Re sum amp exp(lam t), exact
    # per mode: sum_k F_k * K(lag), K from the same FOH integrals computed independently
    lam = np.asarray(model.poles)
    gl_x, gl_w = np.polynomial.legendre.leggauss(16)
    s = 0.5 * (gl_x + 1)
    w = 0.5 * gl_w * dt
    rise = (np.exp(lam[None, :] * (1 - s)[:, None] * dt) * (s * w)[:, None]).sum(0)
    fall = (np.exp(lam[None, :] * (-s)[:, None] * dt) * ((1 - s) * w)[:, None]).sum(0)
    x_conv = np.zeros(n)
    for i in range(1, n):
        lags = i - np.arange(i + 1)
        e = np.exp(lam[None, :] * lags[:, None] * dt)
        kern = np.where((np.arange(i + 1) > 0)[:, None], e * rise, 0) + np.where(
            (lags > 0)[:, None], e * fall, 0)
        x_conv[i] = np.real(force[: i + 1] @ (kern @ amp))
    assert np.max(np.abs(x_ss - x_conv)) <= 1e-8 * np.max(np.abs(x_conv))


# ---------------------------------------------------------------- bad input
@pytest.mark.parametrize("field", ["pad_stiffness", "ballast_damping", "bending_stiffness"])
def test_bad_track_parameters(field):
    with pytest.raises(ValueError, match=field):
        track(**{field: -1.0})
    with pytest.raises(ValueError, match=field):
        track(**{field: float("nan")})


def test_bad_elements_per_bay():
    with pytest.raises(ValueError, match="elements_per_bay"):
        track(elements_per_bay=0)


def test_bad_arguments(model):
    tr = track()
    with pytest.raises(ValueError, match="speed"):
        greens_mod.moving_greens(tr, 0.0, model=model)
    with pytest.raises(ValueError, match="speed"):
        greens_mod.moving_greens(tr, -3.0, model=model)
    with pytest.raises(ValueError, match="speed"):
        greens_mod.moving_greens(tr, float("nan"), model=model)
    with pytest.raises(ValueError, match="duration"):
        greens_mod.moving_greens(tr, 10.0, duration=-1.0, model=model)
    with pytest.raises(ValueError, match="freqs"):
        T.receptance(tr, [np.nan])
    with pytest.raises(ValueError, match="x must"):
        T.receptance(tr, [10.0], x=100.0)
    with pytest.raises(ValueError, match="max_frequency"):
        T.modal_model(tr, max_frequency=0.0)
    with pytest.raises(ValueError, match="force"):
        T.static_deflection(tr, -1.0)


# ---------------------------------------------------------------- cache
def test_cache_roundtrip_corruption_and_env(tmp_path, monkeypatch):
    calls = []

    def build():
        calls.append(1)
        return {"a": np.arange(5.0), "b": np.array([1 + 2j])}

    key = {"x": 1.0, "arr": np.ones(3)}
    out = _cache.load_or_build("unit", key, build, tmp_path)
    again = _cache.load_or_build("unit", key, build, tmp_path)
    assert len(calls) == 1
    np.testing.assert_array_equal(out["a"], again["a"])
    # corrupt the payload: detected by the checksum, rebuilt and rewritten
    path = _cache.cache_path("unit", key, tmp_path)
    blob = bytearray(path.read_bytes())
    blob[-10] ^= 0xFF
    path.write_bytes(bytes(blob))
    again = _cache.load_or_build("unit", key, build, tmp_path)
    assert len(calls) == 2 and np.array_equal(again["b"], [1 + 2j])
    assert _cache._read(path) is not None
    # truncated file
    path.write_bytes(path.read_bytes()[:40])
    _cache.load_or_build("unit", key, build, tmp_path)
    assert len(calls) == 3
    # a different key is a different entry; no temporary files left behind
    _cache.load_or_build("unit", {"x": 2.0, "arr": np.ones(3)}, build, tmp_path)
    assert len(calls) == 4
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".")]
    # location from the environment
    monkeypatch.setenv("WFJAX_CACHE_DIR", str(tmp_path / "env"))
    assert _cache.cache_directory() == tmp_path / "env"
    _cache.load_or_build("unit", key, build)
    assert (tmp_path / "env").is_dir() and len(calls) == 5


def test_track_modal_model_cached(tmp_path):
    tr = track(n_bays=8, elements_per_bay=4)
    m1 = T.modal_model(tr, cache_dir=tmp_path)
    files = list(tmp_path.iterdir())
    assert len(files) == 1
    m2 = T.modal_model(tr, cache_dir=tmp_path)
    np.testing.assert_array_equal(np.asarray(m1.shapes), np.asarray(m2.shapes))
    T.modal_model(track(n_bays=8, elements_per_bay=4, pad_stiffness=100e6),
                  cache_dir=tmp_path)
    assert len(list(tmp_path.iterdir())) == 2


@pytest.mark.slow
def test_receptance_track_length_is_converged_outside_the_pinned_pinned_band():
    """The point receptances on guards.RECEPTANCE_BAYS bays are within 0.5 % of a track twice
    as long over 20 Hz - 2 kHz outside the pinned-pinned band (900-990 Hz), where no finite
    clamped track converges pointwise (benchmarks/receptance_length.py)."""
    from wfjax.scenario import guards

    f = np.geomspace(20.0, 2000.0, 200)
    f = f[(f < 900.0) | (f > 990.0)]
    for x in (0.0, LS / 2):
        h = T.receptance(track(n_bays=guards.RECEPTANCE_BAYS), f, x)
        long = T.receptance(track(n_bays=2 * guards.RECEPTANCE_BAYS), f, x)
        assert np.max(np.abs(h - long) / np.abs(long)) < 5e-3


def test_receptance_command_uses_the_infinite_periodic_track(tmp_path):
    """``wfjax receptance`` writes the infinite periodic track's receptances (no clamped ends
    to shape the pinned-pinned peak), and its pinned-pinned frequency is that track's."""
    import json

    from wfjax.cli import main

    assert main(["receptance", "--points", "120", "--out", str(tmp_path)]) == 0
    summary = json.loads((tmp_path / "receptance.json").read_text())
    assert summary["track_model"] == "infinite periodic"
    rows = np.genfromtxt(tmp_path / "receptance.csv", delimiter=",", names=True)
    grid = np.geomspace(20.0, 5000.0, 120)  # the command's frequencies (20 Hz - 5 kHz)
    mid = T.periodic_receptance(track(), grid, LS / 2)
    np.testing.assert_allclose(rows["track_midspan_re_m_per_N"], mid.real, rtol=1e-6,
                               atol=1e-8 * np.abs(mid).max())
    f = np.geomspace(700.0, 1200.0, 400)
    peak = f[np.argmax(np.abs(T.periodic_receptance(track(), f, LS / 2)))]
    near = grid[np.argmin(np.abs(grid - peak))]
    assert summary["pinned_pinned_hz"] == pytest.approx(near, rel=1e-9)


def test_receptance_of_a_hanging_track_falls_back_to_a_long_finite_track():
    """Every sleeper hanging has no static support on an infinite track: the command uses the
    finite track lengthened to guards.RECEPTANCE_BAYS instead."""
    from wfjax.commands.receptance import _track_receptances
    from wfjax.scenario import guards

    _, static, model = _track_receptances(track(ballast_gap=1e-3), np.array([100.0]),
                                          118e3)
    assert model == f"finite, {guards.RECEPTANCE_BAYS} bays"
    assert np.all(np.isfinite(static))

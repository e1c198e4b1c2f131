"""Measured 3D flats (Flat.from_sections): today's arc-cut profile reproduced on every contact
model, a laterally varying surface against direct Kalker solves on its closed-form gap, the
asymmetric contact, and gradients reaching the record values."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from wfjax.contact import geometry3d, kalker, laws, tables, windows
from wfjax.contact import table_spec as ts
from wfjax.model import geometry, surface
from wfjax.params import Flat, Material, SimConfig, Track, Wheel

F64 = SimConfig(precision="float64")  # identities to rounding: the float64 loop

RR = 0.45  # rail head radius of the comparison track [m]
RW = 0.45


def _arc(y):
    return RR - np.sqrt(RR**2 - y**2)


def _profile_pair(half=0.01, depth=0.1e-3, max_force=150e3):
    """A from_profile flat and its sections: the arc-cut profile (before the clip) sampled on
    the lines of its table grid (so the table's elements sit on the measured lines)."""
    x = np.linspace(-half, half, 21)
    z = depth * np.clip(1 - (x / (0.9 * half)) ** 2, 0, None)
    fp = Flat.from_profile(x, z, wheel_radius=RW)
    spec = ts.table_spec(fp, RW, RR, max_force=max_force)
    y = spec.y
    fs = Flat.from_sections(x, y, z[None, :] - _arc(y)[:, None], wheel_radius=RW)
    return fp, fs, spec


def test_spline_exact_at_nodes_and_linear():
    y = np.array([-0.02, -0.011, -0.003, 0.0, 0.008, 0.02])
    w = surface.spline_weights(y, y)
    assert np.array_equal(w, np.eye(len(y)))
    q = np.linspace(-0.02, 0.02, 41)
    lin = 3.0 + 2.0 * y
    assert np.allclose(surface.spline_weights(y, q) @ lin, 3.0 + 2.0 * q, atol=1e-14)
    # jnp agrees with np
    assert np.allclose(np.asarray(surface.spline_weights(jnp.asarray(y), jnp.asarray(q), jnp)),
                       surface.spline_weights(y, q), atol=1e-14)


def test_outside_band_follows_rail_arc():
    x = np.linspace(-0.01, 0.01, 11)
    y = np.array([-0.005, 0.0, 0.005])
    z = np.tile(0.2e-3 * (1 - np.abs(x) / 0.01), (3, 1))
    f = Flat.from_sections(x, y, z)
    r = np.asarray(geometry.flat_surface(f, np.array([0.0]), np.array([0.005, 0.012]), RR))
    assert r[0, 0] == pytest.approx(0.2e-3, abs=1e-15)
    assert r[0, 1] == pytest.approx(0.2e-3 - (_arc(0.012) - _arc(0.005)), abs=1e-15)


def test_sections_reproduce_from_profile_gap_onset_windows():
    fp, fs, spec = _profile_pair()
    assert fs.depth == fp.depth and fs.half_extent == fp.half_extent
    assert ts.table_spec(fs, RW, RR, max_force=150e3) == spec  # profiles are not mirrored
    xs = np.linspace(-0.03, 0.03, 2001)
    assert np.max(np.abs(np.asarray(geometry.profile_deviation(fs, xs))
                         - np.asarray(geometry.profile_deviation(fp, xs)))) < 1e-15
    s = spec.s
    for xp in (np, jnp):  # the table's (np) and the direct mode's (jnp) gaps
        d = (np.asarray(geometry3d._gap(fs, s, spec.x, spec.y, RW, RR, xp))
             - np.asarray(geometry3d._gap(fp, s, spec.x, spec.y, RW, RR, xp)))
        assert np.max(np.abs(d)) < 1e-15
    assert np.max(np.abs(ts.rigid_onset(spec, fs, s, np) - ts.rigid_onset(spec, fp, s, np))) \
        < 1e-15
    pf, ps = (windows.window_plan(spec, f, s) for f in (fp, fs))
    assert pf.sizes == ps.sizes and np.array_equal(pf.x0, ps.x0) and np.array_equal(pf.y0,
                                                                                   ps.y0)


@pytest.mark.slow
def test_sections_reproduce_from_profile_hertz_winkler_laws():
    fp, fs, _ = _profile_pair()
    wheel, track, mat, cfg = Wheel(), Track.comparison(), Material(), SimConfig()
    delta, sj = (a.ravel() for a in np.meshgrid(np.linspace(0.0, 0.3e-3, 7),
                                                 np.linspace(-0.015, 0.015, 31)))

    @jax.jit
    def forces(law):
        return jax.vmap(law.force)(delta, sj)

    for contact in ("hertz-profile", "hertz-trajectory", "2d"):
        fa, fb = (np.asarray(forces(laws.prepare(contact, f, wheel, track, mat, cfg)))
                  for f in (fp, fs))
        assert np.max(fa) > 1e3
        assert np.max(np.abs(fa - fb)) <= 1e-9 * np.max(fa), contact


def test_sections_reproduce_from_profile_table():
    fp, fs, _ = _profile_pair()
    ta, tb = (tables.build_table_3d(f, RW, RR, max_force=150e3) for f in (fp, fs))
    for name in ("onset", "force", "slope"):
        a, b = np.asarray(getattr(ta, name)), np.asarray(getattr(tb, name))
        assert np.max(np.abs(a - b)) <= 1e-9 * np.max(np.abs(a)), name


@pytest.mark.slow
def test_sections_reproduce_from_profile_simulation():
    """End to end, every built-in model but the direct mode (its inputs, the gap and the
    window plan, are compared above), on the comparison track."""
    import wfjax as wf

    fp, fs, _ = _profile_pair(half=0.02, depth=0.3e-3)
    for contact in ("hertz-profile", "hertz-trajectory", "2d", "3d"):
        a, b = (np.asarray(wf.simulate(f, 30.0, contact=contact, track=Track.comparison(),
                                       config=F64).force)
                for f in (fp, fs))
        assert np.max(np.abs(a - b)) <= 1e-9 * np.max(a), contact


@pytest.mark.slow
def test_sections_reproduce_from_profile_direct_mode():
    """The direct 3D mode's per-step Kalker solves (windowed, from the law) agree."""
    fp, fs, _ = _profile_pair()
    cfg = SimConfig(contact_mode_3d="direct")
    la, lb = (laws.prepare("3d", f, Wheel(), Track.comparison(), Material(), cfg)
              for f in (fp, fs))
    pts = [(-0.004, 0.12e-3), (0.0, 0.15e-3), (0.006, 0.1e-3)]
    for law_a, law_b in ((la, lb),):
        for s, delta in pts:
            p0 = law_a.init_state()
            fa = float(jax.jit(law_a._evaluate)(s, delta, p0)[0])
            fb = float(jax.jit(law_b._evaluate)(s, delta, p0)[0])
            assert fa > 1e3 and abs(fa - fb) <= 1e-9 * fa, (s, delta, fa, fb)


# -- a laterally varying surface with a closed-form gap -----------------------------------------
D, A, B = 0.15e-3, 0.012, 0.03  # depth [m], half length [m], lateral tilt length [m]
XN = np.linspace(-0.02, 0.02, 41)  # record nodes (1 mm; 0 and +-A are nodes)
YN = np.array([-0.04, -0.02, -0.005, 0.0, 0.01, 0.04])  # uneven lines, band wider than grid


def _tilted():
    """S(x, y) = D (1 - |x|/A)_+ (1 + y/B) - 0.02 mm: piecewise linear in x on the nodes and
    linear in y, so the interpolation is exact and the gap is closed-form."""
    z = (D * np.clip(1 - np.abs(XN) / A, 0, None) - 2e-5)[None, :] * 1.0
    z = z + (D * np.clip(1 - np.abs(XN) / A, 0, None))[None, :] * (YN / B)[:, None]
    return Flat.from_sections(XN, YN, z, wheel_radius=RW)


def _closed_gap(s, x, y):
    xs = x[:, None] + s
    r = D * np.clip(1 - np.abs(xs) / A, 0, None) * (1 + y[None, :] / B) - 2e-5
    r = np.where(np.abs(xs) <= 0.02, r, 0.0)
    return (RW - np.sqrt(RW**2 - x**2))[:, None] + _arc(y)[None, :] + np.maximum(r, 0.0)


def test_tilted_gap_closed_form():
    f = _tilted()
    x, y = np.linspace(-0.02, 0.02, 37), np.linspace(-0.018, 0.018, 31)
    for s in (-0.013, 0.0, 0.0047):
        g = np.asarray(geometry3d.gap_3d(f, s, x, y, RW, RR))
        assert np.max(np.abs(g - _closed_gap(s, x, y))) < 1e-15


def test_tilted_table_equals_direct_kalker():
    f = _tilted()
    spec = ts.table_spec(f, RW, RR, max_force=150e3)
    table = tables.build_table_3d(f, RW, RR, max_force=150e3, spec=spec)
    force = np.asarray(table.force)
    fmax = force.max()
    cs = np.concatenate([[0.0], ts.compression_nodes(spec)])
    for j in (spec.n_s // 2 - 9, spec.n_s // 2, spec.n_s // 2 + 4):
        s = spec.s[j]
        gap = _closed_gap(s, spec.x, spec.y)
        assert float(table.onset[j]) <= gap.min() + 1e-15
        for k in (3, 9, spec.n_t - 1):
            r = kalker.solve(gap, spec.element_size, spec.element_size,
                             approach=float(table.onset[j]) + cs[k], tol=1e-10,
                             validate=False)
            assert abs(float(r.force) - force[j, k]) <= 1e-6 * fmax, (j, k)


def test_contact_asymmetric_when_surface_is():
    f = _tilted()
    fp, _, _ = _profile_pair(half=0.02, depth=D)
    x, y = np.linspace(-0.02, 0.02, 41), np.linspace(-0.02, 0.02, 41)
    out = []
    for flat in (f, fp):
        gap = np.asarray(geometry3d.gap_3d(flat, 0.0, x, y, RW, RR))
        r = kalker.solve(gap, 1e-3, 1e-3, force=100e3)
        p = np.asarray(r.pressure)
        out.append((np.sum(p.sum(0) * y) / p.sum(), np.asarray(r.contact)))
    (yc, mask), (yc0, mask0) = out
    assert np.array_equal(mask0, mask0[:, ::-1]) and abs(yc0) < 1e-9
    assert not np.array_equal(mask, mask[:, ::-1])
    assert yc < -1e-4  # the surface is shallower at y < 0: the load moves there


@pytest.mark.slow
def test_gradient_reaches_sections_fd():
    f = _tilted()
    x, y = np.linspace(-0.012, 0.012, 25), np.linspace(-0.012, 0.012, 25)

    @jax.jit
    def force(z):
        fl = Flat("sections", f.depth, f.length, f.wheel_radius, profile_x=f.profile_x,
                  section_y=f.section_y, section_z=z)
        gap = geometry3d.gap_3d(fl, 0.002, x, y, RW, RR)
        return kalker.solve(gap, 1e-3, 1e-3, approach=0.1e-3, tol=1e-12).force

    z0 = jnp.asarray(f.section_z)
    g = np.asarray(jax.grad(force)(z0))
    assert np.any(np.abs(g) > 0)
    for i, j in ((3, 20), (2, 23), (4, 18)):  # lines at 0, -5 and 10 mm
        e = np.zeros_like(np.asarray(z0))
        e[i, j] = 1e-8
        fd = (float(force(z0 + e)) - float(force(z0 - e))) / 2e-8
        assert g[i, j] == pytest.approx(fd, rel=2e-3, abs=1e-3 * np.max(np.abs(g)))

    @jax.jit
    def drop(z):  # the Hertz models' path: the centre line's rigid trajectory
        fl = Flat("sections", f.depth, f.length, f.wheel_radius, profile_x=f.profile_x,
                  section_y=f.section_y, section_z=z, extent_bound=0.02)
        return jnp.sum(geometry.centre_trajectory(fl, jnp.linspace(-0.01, 0.01, 21)))

    g2 = np.asarray(jax.grad(drop)(z0))
    e = np.zeros_like(np.asarray(z0))
    e[3, 18] = 1e-8
    fd = (float(drop(z0 + e)) - float(drop(z0 - e))) / 2e-8
    assert g2[3, 18] == pytest.approx(fd, rel=1e-4, abs=1e-9)


def test_from_sections_refuses_bad_input():
    x = np.linspace(-0.01, 0.01, 11)
    z = np.full((2, 11), 1e-4)
    with pytest.raises(ValueError, match="strictly increasing"):
        Flat.from_sections(x, [0.005, -0.005], z)
    with pytest.raises(ValueError, match="contain the contact line"):
        Flat.from_sections(x, [0.005, 0.01], z)
    with pytest.raises(ValueError, match="exceeds"):
        Flat.from_sections(x, [-0.005, 0.005], z * 60)
    with pytest.raises(ValueError, match="shapes"):
        Flat.from_sections(x, [-0.005, 0.005], z[:, :5])

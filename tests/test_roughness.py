"""Rail and wheel roughness (wfjax.scenario.roughness): generation against its target spectrum, the
band estimator against sinusoids, the CSV reader, the contact filter against its analytic
response, and bad input."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from wfjax.scenario import patch
from wfjax.scenario import roughness as R


def _write(path, text):
    path.write_text(text)
    return path


# ---------------------------------------------------------------- spectrum
def test_generated_roughness_reproduces_iso3095_within_1db():
    """20 realisations of 20 m at 0.25 mm: the energy-averaged band levels are the target
    within 1 dB in every band (0.4 m to 3.15 mm), and one realisation scatters about it."""
    target = R.ISO3095_LIMIT
    rough = R.generate(target, jax.random.PRNGKey(2014), length=20.0, spacing=2.5e-4,
                       n_realisations=20)
    assert rough.values.shape == (20, 80000)
    levels = R.third_octave_spectrum(rough.values, rough.spacing, target.wavelengths)
    avg = R.energy_average(levels, axis=0)
    assert np.max(np.abs(avg - target.levels_db)) < 1.0
    assert np.all(levels.std(axis=0) > 0.05)  # random amplitudes, not a fixed spectrum
    assert abs(np.mean(rough.values)) < 1e-9 and np.max(np.abs(rough.values)) < 1e-4


def test_band_estimator_on_sinusoids():
    """A sinusoid of amplitude A at a band centre reads 20 log10(A / sqrt 2 / 1 um) in its
    band and nothing in the others; two sinusoids in one band add their energies."""
    dx, n = 2.5e-4, 40000  # 10 m: 0.1 m and 0.02 m are whole numbers of periods
    x = np.arange(n) * dx
    a1, a2 = 3e-6, 1e-6
    r = a1 * np.sin(2 * np.pi * x / 0.1) + a2 * np.cos(2 * np.pi * x / 0.02 + 0.3)
    lam = np.array([0.1, 0.05, 0.02])
    lev = R.third_octave_spectrum(r, dx, lam)
    np.testing.assert_allclose(lev[[0, 2]], 20 * np.log10(np.array([a1, a2]) / np.sqrt(2) / 1e-6),
                               atol=1e-9)
    assert lev[1] < -200
    both = a1 * (np.sin(2 * np.pi * x / 0.1) + np.sin(2 * np.pi * x * 10.4))  # 96 mm
    assert R.third_octave_spectrum(both, dx, lam)[0] == pytest.approx(
        10 * np.log10(a1**2 / 1e-12), abs=1e-9)


def test_generation_is_reproducible_and_realisations_differ():
    spec = R.BandSpectrum(np.array([0.05, 0.01]), np.array([0.0, -6.0]))
    a = R.generate(spec, 5, length=2.0, spacing=5e-4)
    b = R.generate(spec, jax.random.PRNGKey(5), length=2.0, spacing=5e-4)
    np.testing.assert_array_equal(a.values, b.values)
    c = R.generate(spec, 5, length=2.0, spacing=5e-4, n_realisations=3)
    assert c.values.shape == (3, 4000) and not np.allclose(c.values[0], c.values[1])


def test_wheel_roughness_is_periodic_with_the_circumference():
    w = R.generate_wheel(R.ISO3095_LIMIT, 3, wheel_radius=0.45, spacing=2.5e-4)
    circ = 2 * np.pi * 0.45
    assert w.periodic and w.length == pytest.approx(circ, rel=1e-12)
    s = jnp.linspace(-0.3, 0.3, 101)
    np.testing.assert_allclose(R.roughness_at(w, s + circ), R.roughness_at(w, s), atol=1e-15)
    np.testing.assert_allclose(R.roughness_at(w, s - 2 * circ), R.roughness_at(w, s),
                               atol=1e-15)
    # across the seam the profile is as smooth as anywhere: its slope is of the usual size
    d = np.diff(np.asarray(R.roughness_at(w, jnp.linspace(-1e-3, 1e-3, 9))))
    assert np.max(np.abs(d)) < 5 * np.std(np.diff(w.values))


# ---------------------------------------------------------------- CSV
def test_read_csv_units_and_wheel(tmp_path):
    x = np.arange(200) * 0.5  # mm
    r = 2.0 * np.sin(2 * np.pi * x / 25.0)  # um
    text = "# measured\nx_mm,roughness_um\n" + "".join(f"{a:.3f},{b:.6f}\n" for a, b in
                                                          zip(x, r, strict=True))
    rough = R.read_csv(_write(tmp_path / "rail.csv", text))
    assert not rough.periodic and rough.spacing == pytest.approx(5e-4)
    np.testing.assert_allclose(rough.values, r * 1e-6, atol=1e-12)
    np.testing.assert_allclose(R.roughness_at(rough, 0.01), 2e-6 * np.sin(2 * np.pi * 10 / 25),
                               rtol=2e-2)
    # rail ends: the end values are held
    assert float(R.roughness_at(rough, -1.0)) == pytest.approx(rough.values[0])
    shifted = R.read_csv(tmp_path / "rail.csv", x_start=3.0)
    assert float(shifted.x_start) == 3.0
    # a wheel profile over one circumference (R = 0.1 m, 1257 samples of 0.5 mm)
    n = 1257
    xs = np.arange(n) * 2 * np.pi * 0.1 / n
    _write(tmp_path / "wheel.csv", "x_m,roughness_m\n" + "".join(
        f"{float(a)!r},{float(1e-6 * np.cos(a / 0.1))!r}\n" for a in xs))
    w = R.read_csv(tmp_path / "wheel.csv", wheel_radius=0.1)
    assert w.periodic and w.length == pytest.approx(2 * np.pi * 0.1)
    with pytest.raises(ValueError, match=r"one circumference"):
        R.read_csv(tmp_path / "wheel.csv", wheel_radius=0.12)


@pytest.mark.parametrize("text,match", [
    ("x,r\n0,1\n1,2\n2,3\n3,4\n", r"columns must be one of \['x_m', 'x_mm'\]"),
    ("x_mm,roughness_um,extra\n0,1,1\n", "columns must be"),
    ("x_mm,roughness_um\n0,1\n0.5,abc\n1,1\n1.5,1\n", r"row 3 must hold two numbers"),
    ("x_mm,roughness_um\n0,1\n0.5,nan\n1,1\n1.5,1\n", "must be finite"),
    ("x_mm,roughness_mm\n0,1\n0.5,6\n1,1\n1.5,1\n", r"within \+-5 mm, got 6 mm"),
    ("x_mm,roughness_um\n0,1\n2,2\n4,1\n6,1\n", r"2 mm is too coarse .* at most 1 mm"),
    ("x_mm,roughness_um\n0,1\n0.5,2\n0.7,1\n1.5,1\n", "uniformly spaced"),
    ("x_mm,roughness_um\n0,1\n0.5,2\n", "at least 4 rows"),
    ("", "empty file"),
])
def test_read_csv_bad_input(tmp_path, text, match):
    with pytest.raises(ValueError, match=match) as err:
        R.read_csv(_write(tmp_path / "bad.csv", text))
    assert "\n" not in str(err.value) and "bad.csv" in str(err.value)


def test_bad_generation_and_profiles():
    spec = R.ISO3095_LIMIT
    with pytest.raises(ValueError, match=r"too coarse for the contact: at most 1 mm"):
        R.generate(spec, 0, length=10.0, spacing=2e-3)
    with pytest.raises(ValueError, match=r"1.6 mm band gets no Fourier component .* need "
                                         r"spacing < 0.713"):
        R.generate(R.BandSpectrum(np.array([0.0016]), np.array([0.0])), 0, 1.0, spacing=1e-3)
    with pytest.raises(ValueError, match=r"400 mm band .* need length >= 1.73 m"):
        R.generate(spec, 0, length=1.0, spacing=2.5e-4)
    with pytest.raises(ValueError, match=r"levels_db must be <= 60 dB"):
        R.generate(R.BandSpectrum(np.array([0.1]), np.array([80.0])), 0, 5.0)
    with pytest.raises(ValueError, match=r"length must be finite and > 0 m"):
        R.generate(spec, 0, length=-1.0)
    with pytest.raises(ValueError, match=r"within \+-5 mm"):
        R.Roughness(0.0, 1e-4, np.array([0.0, 6e-3, 0.0]))
    with pytest.raises(ValueError, match=r"must be finite, got a non-finite value at sample 1"):
        R.Roughness(0.0, 1e-4, np.array([0.0, np.nan, 0.0]))
    with pytest.raises(ValueError, match=r"spacing must be in \(0, 1\] mm"):
        R.Roughness(0.0, 5e-3, np.zeros(3))
    with pytest.raises(ValueError, match="kind must be one of"):
        patch.contact_filter(R.Roughness(0.0, 1e-4, np.zeros(3)), 0.0, 0.01, kind="box")


# ---------------------------------------------------------------- contact filter
@pytest.mark.parametrize("kind", ["ellipse", "mean"])
@pytest.mark.parametrize("wavelength", [0.2, 0.05, 0.02, 0.011, 0.006])
def test_contact_filter_matches_its_analytic_response(kind, wavelength):
    """A sinusoid through the filter: amplitude times the analytic response (12 mm patch),
    within 1 % of the amplitude, including the lobes beyond the first zero."""
    dx = 1e-4
    x = np.arange(-2000, 2001) * dx
    amp = 1e-5
    rough = R.Roughness(float(x[0]), dx, amp * np.cos(2 * np.pi * x / wavelength))
    xc = jnp.linspace(-0.05, 0.05, 41)
    length = 0.012
    got = patch.contact_filter(rough, xc, length, kind=kind, n_points=64)
    want = amp * patch.contact_filter_response(wavelength, length, kind) * np.cos(
        2 * np.pi * np.asarray(xc) / wavelength)
    np.testing.assert_allclose(got, want, atol=0.01 * amp)


@pytest.mark.slow
def test_contact_filter_in_jit_vmap_grad():
    rough = R.generate(R.BandSpectrum(np.array([0.05, 0.02]), np.array([0.0, -3.0])), 1,
                       length=1.0, spacing=2.5e-4, n_realisations=4)
    f = jax.jit(lambda x, a: patch.contact_filter(rough, x, a))
    out = f(jnp.array([0.1, 0.2]), 0.011)
    assert out.shape == (4, 2)
    # vmap over realisations through the values leaf
    one = dataclasses.replace(rough, values=rough.values[0])
    per = jax.vmap(lambda v: patch.contact_filter(dataclasses.replace(one, values=v), 0.1, 0.011))(
        jnp.asarray(rough.values))
    np.testing.assert_allclose(per, out[:, 0], rtol=1e-12)
    # traced contact length: the derivative exists and matches a finite difference
    g = jax.grad(lambda a: patch.contact_filter(one, 0.1, a))(0.011)
    fd = (patch.contact_filter(one, 0.1, 0.011 + 1e-6)
          - patch.contact_filter(one, 0.1, 0.011 - 1e-6)) / 2e-6
    assert float(g) == pytest.approx(float(fd), rel=2e-2)  # piecewise-linear profile
    # a tiny patch reads the profile itself
    np.testing.assert_allclose(patch.contact_filter(one, 0.1234, 1e-7), R.roughness_at(one, 0.1234),
                               rtol=1e-6)

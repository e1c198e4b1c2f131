"""Rail and wheel roughness: profiles from files or random from a one-third-octave spectrum,
their spectra, and the contact filter that turns them into a point-contact input.

Convention: ``r(x)`` [m] is the height of the running surface, **positive = surface raised**
(toward the other body: it closes the gap, so it adds to the penetration; a flat, which
removes material, enters with the other sign). Roughness is transversely uniform (the same
across the contact width). Rail roughness is a function of the rail position ``x`` [m] (the
track's coordinate: ``x = 0`` above the middle sleeper); wheel roughness is a function of the
circumferential coordinate ``s`` [m] and periodic with the circumference ``2 pi R``.

Inputs:

* :func:`read_csv` -- a measured profile, two columns with the unit in the name:
  ``x_m`` or ``x_mm``, then ``roughness_m``, ``roughness_mm`` or ``roughness_um``;
  uniformly spaced; ``wheel_radius=R`` makes it a wheel profile over one circumference.
* :func:`generate` / :func:`generate_wheel` -- a Gaussian random profile whose expected
  one-third-octave band levels are a :class:`BandSpectrum` (dB re 1 um over wavelength
  bands), from a ``jax.random`` key; :data:`ISO3095_LIMIT` is the ISO 3095 limit curve.

Reading (pure ``jax.numpy``, inside ``jit``): :func:`roughness_at` (the profile at points)
and :func:`contact_filter` (its average over the contact length, weighted by the width of
the elliptical contact patch: the equivalent input of a point-contact law).
:func:`third_octave_spectrum` gives the band levels of a profile.

Limits (:data:`MAX_SPACING`, :data:`MAX_AMPLITUDE`): samples at most 1 mm apart, because the
contact patch is about 10-12 mm long under a 118 kN wheel (the contact filter must average
over ten samples or more) and the 2D bedding and direct 3D contact read the gap on 1 mm
elements (``SimConfig.contact_element``); amplitudes at most 5 mm, the model's deepest flat,
so a rail profile may carry a dipped joint (0.5-3 mm, :mod:`wfjax.scenario.joint`).
"""

from __future__ import annotations

import csv
import math
import os
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..fields import is_concrete, pytree
from ..model.supports import as_key
from ..model.track import check_positive_scalar

__all__ = [
    "Roughness",
    "BandSpectrum",
    "ISO3095_LIMIT",
    "MAX_SPACING",
    "MAX_AMPLITUDE",
    "read_csv",
    "generate",
    "generate_wheel",
    "third_octave_spectrum",
    "energy_average",
    "roughness_at",
]

MAX_SPACING = 1e-3  # m
MAX_AMPLITUDE = 5e-3  # m (= params.MAX_FLAT_DEPTH; see the module docstring)
REFERENCE = 1e-6  # m: 0 dB re 1 um
X_COLUMNS = {"x_m": 1.0, "x_mm": 1e-3}
R_COLUMNS = {"roughness_m": 1.0, "roughness_mm": 1e-3, "roughness_um": 1e-6}


class BandSpectrum(NamedTuple):
    """A one-third-octave roughness spectrum.

    Fields:
        wavelengths: float [n_b] band centre wavelengths [m] (nominal values; the bands are
            base-10 one-third octaves, edges ``lambda_c * 10^(+-1/20)``).
        levels_db: float [n_b] band levels [dB re 1 um]: 10 log10(mean square in the band /
            (1 um)^2).
    """

    wavelengths: np.ndarray
    levels_db: np.ndarray


ISO3095_LIMIT = BandSpectrum(
    np.array([0.4, 0.315, 0.25, 0.2, 0.16, 0.125, 0.1, 0.08, 0.063, 0.05, 0.04, 0.0315,
              0.025, 0.02, 0.016, 0.0125, 0.01, 0.008, 0.0063, 0.005, 0.004, 0.00315]),
    np.array([17.1, 15.0, 13.0, 11.0, 9.0, 7.0, 4.9, 2.9, 0.9, -1.1, -3.2, -5.0, -5.6, -6.2,
              -6.8, -7.4, -8.0, -8.6, -9.2, -9.8, -10.4, -11.0]))
"""The rail roughness limit of the ISO 3095 reference track (ISO 3095:2013, 6.2.5 and
Figure 2: a test track's rail roughness must not exceed it in any band), one-third-octave
bands from 0.4 m to 3.15 mm, dB re 1 um. Numbers as tabulated in the open-source
``phonometry`` package (J. M. Requena Plens, ``environment.sources.rolling_stock_noise.
REFERENCE_TRACK_ROUGHNESS_LIMIT_DB``, read from ISO 3095:2013); the standard asks for
0.003-0.10 m up to 190 km/h and 0.003-0.25 m above."""


def _band_edges(wavelengths) -> tuple[np.ndarray, np.ndarray]:
    """Wavenumber edges [1/m] (low, high) of the base-10 one-third-octave bands."""
    lam = np.asarray(wavelengths, dtype=float)
    return 10 ** (-1 / 20) / lam, 10 ** (1 / 20) / lam


def _bins_in_bands(n: int, spacing: float, wavelengths) -> np.ndarray:
    """Band index [n // 2 + 1] of every rfft bin of an n-sample profile (-1: in no band).

    Bin j has wavenumber j / (n spacing); the mean (j = 0) and the Nyquist bin are left out.
    A bin on a band edge belongs to the band above it in wavenumber (low edge inclusive).
    """
    k = np.arange(n // 2 + 1) / (n * spacing)
    lo, hi = _band_edges(wavelengths)
    band = np.full(k.size, -1)
    for b in range(lo.size):
        band[(k >= lo[b]) & (k < hi[b])] = b
    band[0] = -1
    if n % 2 == 0:
        band[-1] = -1
    return band


# --------------------------------------------------------------------------------------------
# the profile
# --------------------------------------------------------------------------------------------
def _fail(msg: str):
    raise ValueError(msg)


@pytree(static=("periodic",))
class Roughness:
    """A roughness profile sampled on a uniform grid (a pytree: the numbers are leaves).

    Attributes:
        x_start: position of the first sample [m] (rail: rail coordinate; wheel: 0).
        spacing: sample spacing [m], > 0 and <= :data:`MAX_SPACING` (1 mm).
        values: float [n] or [n_realisations, n] roughness [m] (positive = surface raised),
            ``|r| <= MAX_AMPLITUDE`` (5 mm).
        periodic (static): ``True`` for a wheel: ``r(s + n spacing) = r(s)`` (the period is the
            circumference); ``False`` for a rail: beyond the sampled span the end values are
            held (a constant offset, which exerts no dynamic force).

    Build with :func:`read_csv`, :func:`generate`, :func:`generate_wheel`, or directly from
    arrays (validated when concrete). Monte Carlo: a batch ``values [R, n]`` from
    :func:`generate` with ``n_realisations``; map one function over realisations with
    ``jax.vmap(lambda v: f(dataclasses.replace(rough, values=v)))(rough.values)``.
    """

    x_start: Any
    spacing: Any
    values: Any
    periodic: bool = False

    def __post_init__(self):
        if not isinstance(self.periodic, bool):
            _fail(f"Roughness.periodic must be True or False, got {self.periodic!r}")
        if is_concrete(self.spacing):
            dx = float(np.asarray(self.spacing))
            if not math.isfinite(dx) or dx <= 0 or dx > MAX_SPACING * (1 + 1e-9):
                _fail(f"Roughness.spacing must be in (0, {MAX_SPACING * 1e3:g}] mm (the "
                      f"contact patch is ~10 mm long and the contact elements 1 mm), got "
                      f"{dx * 1e3:g} mm")
        if is_concrete(self.x_start) and not math.isfinite(float(np.asarray(self.x_start))):
            _fail(f"Roughness.x_start must be finite, got {self.x_start!r}")
        if is_concrete(self.values):
            v = np.asarray(self.values, dtype=float)
            if v.ndim not in (1, 2) or v.shape[-1] < 2:
                _fail(f"Roughness.values must be [n] or [n_realisations, n] with n >= 2, got "
                      f"shape {v.shape}")
            if not np.all(np.isfinite(v)):
                _fail(f"Roughness.values must be finite, got a non-finite value at sample "
                      f"{int(np.flatnonzero(~np.isfinite(v.ravel()))[0]) % v.shape[-1]}")
            peak = float(np.max(np.abs(v)))
            if peak > MAX_AMPLITUDE:
                _fail(f"Roughness.values must be within +-{MAX_AMPLITUDE * 1e3:g} mm (the "
                      f"deepest flat the model takes), got {peak * 1e3:.4g} mm")

    @property
    def length(self) -> float:
        """Sampled length ``n * spacing`` [m] (the period of a wheel profile)."""
        return float(np.shape(self.values)[-1] * float(np.asarray(self.spacing)))

    @property
    def x(self) -> np.ndarray:
        """Sample positions [m], float [n]."""
        n = np.shape(self.values)[-1]
        return float(np.asarray(self.x_start)) + np.arange(n) * float(np.asarray(self.spacing))


def read_csv(path: str | os.PathLike, wheel_radius: float | None = None,
             x_start: float | None = None) -> Roughness:
    """A measured roughness profile from a CSV file.

    Format: a header row with two columns, the unit in each name -- position ``x_m`` or
    ``x_mm``, then roughness ``roughness_m``, ``roughness_mm`` or ``roughness_um`` -- then one
    row per sample; ``#`` lines are comments. Positions strictly increasing and uniformly
    spaced (within 0.1 % of the spacing; resample first otherwise), at most 1 mm apart.

    Args:
        path: the file.
        wheel_radius: ``None`` for rail roughness (positions are rail coordinates [m]); a
            wheel radius R [m] for wheel roughness: the samples must cover exactly one
            circumference (``n * spacing = 2 pi R`` within half a spacing) and the profile is
            periodic.
        x_start: rail only: shift the profile so its first sample sits at ``x_start`` [m].

    Returns:
        :class:`Roughness` (``values [n]``).

    Raises:
        ValueError: one line naming the file and what is wrong (columns, values, spacing).
    """
    name = os.fspath(path)
    import io

    from .. import limits

    text = limits.read_text(name, name)
    rows = [r for r in csv.reader(line for line in io.StringIO(text, newline="")
                                  if not line.lstrip().startswith("#"))
            if r and any(c.strip() for c in r)]
    if not rows:
        _fail(f"{name}: empty file (need a header x_m|x_mm,roughness_m|roughness_mm|"
              f"roughness_um and rows)")
    head = [c.strip() for c in rows[0]]
    if len(head) != 2 or head[0] not in X_COLUMNS or head[1] not in R_COLUMNS:
        _fail(f"{name}: columns must be one of {sorted(X_COLUMNS)} then one of "
              f"{sorted(R_COLUMNS)}, got {head!r}")
    try:
        data = np.array([[float(c) for c in r] for r in rows[1:]], dtype=float)
    except ValueError:
        bad = next(i for i, r in enumerate(rows[1:], 2) if not _numbers(r))
        raise ValueError(f"{name}: row {bad} must hold two numbers, got "
                         f"{rows[bad - 1]!r}") from None
    if data.ndim != 2 or data.shape[1] != 2 or data.shape[0] < 4:
        _fail(f"{name}: need at least 4 rows of two numbers, got {len(rows) - 1} rows")
    x = data[:, 0] * X_COLUMNS[head[0]]
    r = data[:, 1] * R_COLUMNS[head[1]]
    if not np.all(np.isfinite(x)) or not np.all(np.isfinite(r)):
        _fail(f"{name}: values must be finite")
    dx = (x[-1] - x[0]) / (x.size - 1)
    if np.any(np.diff(x) <= 0):
        _fail(f"{name}: {head[0]} must be strictly increasing")
    if np.max(np.abs(x - (x[0] + dx * np.arange(x.size)))) > 1e-3 * dx:
        _fail(f"{name}: {head[0]} must be uniformly spaced (within 0.1 % of the "
              f"{dx * 1e3:.4g} mm mean spacing); resample the profile first")
    if dx > MAX_SPACING * (1 + 1e-9):
        _fail(f"{name}: sample spacing {dx * 1e3:.4g} mm is too coarse for the contact: at "
              f"most {MAX_SPACING * 1e3:g} mm is needed (the patch is ~10 mm long, the contact "
              f"elements 1 mm)")
    peak = float(np.max(np.abs(r)))
    if peak > MAX_AMPLITUDE:
        _fail(f"{name}: roughness must be within +-{MAX_AMPLITUDE * 1e3:g} mm, got "
              f"{peak * 1e3:.4g} mm (check the unit in '{head[1]}')")
    if wheel_radius is None:
        return Roughness(float(x[0]) if x_start is None else float(x_start), float(dx), r)
    circ = 2 * math.pi * float(wheel_radius)
    if not circ > 0 or abs(x.size * dx - circ) > 0.5 * dx:
        _fail(f"{name}: a wheel profile must cover one circumference 2 pi R = {circ:.6g} m "
              f"(n * spacing within half a spacing), got {x.size} x {dx:.6g} m = "
              f"{x.size * dx:.6g} m")
    return Roughness(0.0, circ / x.size, r, periodic=True)


def _numbers(row) -> bool:
    try:
        [float(c) for c in row]
    except ValueError:
        return False
    return True


# --------------------------------------------------------------------------------------------
# spectra and random profiles
# --------------------------------------------------------------------------------------------
def _check_spectrum(spectrum: BandSpectrum) -> tuple[np.ndarray, np.ndarray]:
    lam = np.asarray(spectrum.wavelengths, dtype=float)
    lev = np.asarray(spectrum.levels_db, dtype=float)
    if lam.ndim != 1 or lam.shape != lev.shape or lam.size == 0:
        _fail(f"spectrum wavelengths and levels_db must be 1-D of equal length, got shapes "
              f"{lam.shape} and {lev.shape}")
    if not np.all(np.isfinite(lam)) or np.any(lam <= 0) or not np.all(np.isfinite(lev)):
        _fail("spectrum wavelengths must be finite and > 0 m and levels_db finite")
    if np.any(lev > 60.0):
        _fail(f"spectrum levels_db must be <= 60 dB re 1 um (1 mm rms), got {lev.max():g} dB")
    return lam, lev


def _grid_check(n: int, spacing: float, lam: np.ndarray) -> np.ndarray:
    band = _bins_in_bands(n, spacing, lam)
    counts = np.bincount(band[band >= 0], minlength=lam.size)
    if np.any(counts == 0):
        b = int(np.flatnonzero(counts == 0)[0])
        need_dx = lam[b] * 10 ** (-1 / 20) / 2  # Nyquist at the band's short edge
        need_len = lam[b] / (10 ** (1 / 20) - 10 ** (-1 / 20))  # 1/L <= the band's width
        need = (f"spacing < {need_dx * 1e3:.4g} mm" if spacing >= need_dx
                else f"length >= {need_len:.3g} m")
        _fail(f"the {lam[b] * 1e3:.4g} mm band gets no Fourier component on {n} samples "
              f"{spacing * 1e3:.4g} mm apart: need {need}")
    return band


def _bin_sigmas(n: int, spacing: float, spectrum: BandSpectrum) -> np.ndarray:
    """Standard deviation [m] of the cos and sin amplitudes of every rfft bin [n // 2 + 1]."""
    lam, lev = _check_spectrum(spectrum)
    band = _grid_check(n, spacing, lam)
    counts = np.bincount(band[band >= 0], minlength=lam.size)
    ms = (REFERENCE**2) * 10 ** (lev / 10)  # mean square per band [m^2]
    return np.where(band >= 0, np.sqrt(ms[band] / np.maximum(counts[band], 1)), 0.0)


def _random_values(key, sigma: np.ndarray, n: int, n_realisations: int | None) -> np.ndarray:
    def one(k):
        ka, kb = jax.random.split(k)
        a = jax.random.normal(ka, sigma.shape, dtype=jnp.float64) * sigma
        b = jax.random.normal(kb, sigma.shape, dtype=jnp.float64) * sigma
        # irfft: bin j of X = (n / 2)(a - i b) is a_j cos(2 pi j m / n) + b_j sin(...)
        return jnp.fft.irfft((n / 2) * (a - 1j * b), n)

    key = as_key(key)
    if n_realisations is None:
        return np.asarray(one(key))
    if not isinstance(n_realisations, (int, np.integer)) or n_realisations < 1:
        _fail(f"n_realisations must be an integer >= 1, got {n_realisations!r}")
    return np.asarray(jax.vmap(one)(jax.random.split(key, int(n_realisations))))


def _check_spacing(spacing) -> float:
    dx = check_positive_scalar("spacing", spacing, "m")
    if dx > MAX_SPACING * (1 + 1e-9):
        _fail(f"spacing {dx * 1e3:g} mm is too coarse for the contact: at most "
              f"{MAX_SPACING * 1e3:g} mm is needed (the patch is ~10 mm long, the contact "
              f"elements 1 mm)")
    return dx


def generate(spectrum: BandSpectrum, key, length: float, spacing: float = 2.5e-4,
             x_start: float = 0.0, n_realisations: int | None = None) -> Roughness:
    """A Gaussian random rail roughness profile with the expected band levels ``spectrum``.

    Method: each Fourier component of the ``n = round(length / spacing)``-sample profile
    (wavenumbers ``j / (n spacing)``) whose wavelength lies in a band of ``spectrum`` gets
    independent normal cosine and sine amplitudes; their variance is the band's mean square
    (``(1 um)^2 10^(L/10)``) shared equally among the band's components, so the expected
    one-third-octave levels (:func:`third_octave_spectrum`) are exactly ``spectrum``; a
    realisation scatters about it (a band with m components: about ``4.3 / sqrt(m)`` dB).
    Wavelengths outside the bands get nothing. The profile is one period of a periodic
    signal; the mean is zero.

    Args:
        spectrum: target band levels (e.g. :data:`ISO3095_LIMIT`).
        key: ``jax.random`` key or integer seed.
        length: profile length [m]; every band needs at least one component (the error
            says what length and spacing a band needs).
        spacing: sample spacing [m] (default 0.25 mm; at most 1 mm).
        x_start: rail position of the first sample [m].
        n_realisations: ``None`` for one profile (``values [n]``), else R independent ones
            (``values [R, n]``, from ``jax.random.split(key, R)``).

    Returns:
        :class:`Roughness` (not periodic).
    """
    dx = _check_spacing(spacing)
    n = int(round(check_positive_scalar("length", length, "m") / dx))
    if n < 4:
        _fail(f"length must be at least 4 spacings ({4 * dx:g} m), got {length!r}")
    values = _random_values(key, _bin_sigmas(n, dx, spectrum), n, n_realisations)
    return Roughness(float(x_start), dx, values)


def generate_wheel(spectrum: BandSpectrum, key, wheel_radius: float = 0.45,
                   spacing: float = 2.5e-4, n_realisations: int | None = None) -> Roughness:
    """A Gaussian random wheel roughness profile, periodic with the circumference.

    As :func:`generate` on ``n = round(2 pi R / spacing)`` samples with the spacing adjusted
    to ``2 pi R / n``: every Fourier component is a harmonic of the wheel's revolution, so
    the profile closes on itself. ``s = 0`` is an arbitrary point of the tread (the time loop
    decides where the wheel starts).

    Args:
        spectrum, key, spacing, n_realisations: as :func:`generate`.
        wheel_radius: R [m].

    Returns:
        :class:`Roughness` with ``periodic=True``.
    """
    circ = 2 * math.pi * check_positive_scalar("wheel_radius", wheel_radius, "m")
    n = int(round(circ / _check_spacing(spacing)))
    dx = circ / n
    values = _random_values(key, _bin_sigmas(n, dx, spectrum), n, n_realisations)
    return Roughness(0.0, dx, values, periodic=True)


def third_octave_spectrum(values, spacing: float, wavelengths=ISO3095_LIMIT.wavelengths):
    """One-third-octave band levels [dB re 1 um] of sampled profiles.

    Narrow-band power of the mean-removed profile by FFT (rectangular window: exact for
    periodic profiles such as :func:`generate`'s; a measured record leaks a little between
    neighbouring bands), summed over the components in each base-10 band
    (edges ``lambda_c 10^(+-1/20)``). A band without components is ``nan``.

    Args:
        values: float [..., n] profiles [m] (any leading batch axes).
        spacing: sample spacing [m].
        wavelengths: [n_b] band centre wavelengths [m] (default: the ISO 3095 bands).

    Returns:
        float [..., n_b] levels: 10 log10(band mean square / (1 um)^2).
    """
    v = np.asarray(values, dtype=float)
    n = v.shape[-1]
    lam = np.asarray(wavelengths, dtype=float)
    band = _bins_in_bands(n, check_positive_scalar("spacing", spacing, "m"), lam)
    x = np.fft.rfft(v - v.mean(axis=-1, keepdims=True), axis=-1)
    power = 2 * np.abs(x) ** 2 / n**2  # mean square of each component (0 < j < n/2)
    out = np.full(v.shape[:-1] + (lam.size,), np.nan)
    for b in range(lam.size):
        sel = band == b
        if np.any(sel):
            out[..., b] = 10 * np.log10(power[..., sel].sum(axis=-1) / REFERENCE**2)
    return out


def energy_average(levels_db, axis: int = 0):
    """Energy average of levels [dB] along ``axis``: 10 log10(mean(10^(L/10)))."""
    return 10 * np.log10(np.mean(10 ** (np.asarray(levels_db) / 10), axis=axis))


# --------------------------------------------------------------------------------------------
# reading the profile inside the time loop
# --------------------------------------------------------------------------------------------
def roughness_at(rough: Roughness, x) -> jax.Array:
    """The profile at positions ``x`` [m] (any shape), linear between samples.

    Rail profiles hold their end values outside the sampled span; wheel profiles
    (``periodic``) wrap. With ``values [R, n]`` the result is ``[R, *x.shape]``. Pure
    ``jax.numpy`` (jit / vmap / grad in ``x`` and in the values).
    """
    values = jnp.asarray(rough.values)
    n = values.shape[-1]
    x = jnp.asarray(x, dtype=jnp.result_type(x, float))
    u = (x - rough.x_start) / rough.spacing
    if rough.periodic:
        u = jnp.mod(u, n)
        i0 = jnp.clip(jnp.floor(u).astype(jnp.int32), 0, n - 1)
        i1 = jnp.where(i0 + 1 >= n, 0, i0 + 1)
    else:
        u = jnp.clip(u, 0.0, n - 1.0)
        i0 = jnp.clip(jnp.floor(u).astype(jnp.int32), 0, n - 2)
        i1 = i0 + 1
    f = u - i0
    return values[..., i0] * (1.0 - f) + values[..., i1] * f



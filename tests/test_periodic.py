"""The infinite periodic track's receptance (wfjax.model.periodic): against the Timoshenko
rail's analytic dispersion, against long finite tracks where they converge, and the finite
tracks' approach to it at the pinned-pinned resonance, where they converge slowly."""

from __future__ import annotations

import math

import numpy as np
import pytest

import wfjax
from wfjax.model import periodic as P
from wfjax.model import track as T
from wfjax.model.beam import track_numbers

LS = 0.65


def _dispersion(p: dict, omega: float) -> tuple[float, float]:
    """(propagating k, evanescent k) [1/m] of the free Timoshenko rail at ``omega``:
    EI k^4 - omega^2 (rho I + EI rho A / kGA) k^2 + rho A omega^2 (rho I omega^2 / kGA - 1)
    = 0."""
    ei, kga = float(p["bending_stiffness"]), float(p["shear_stiffness"])
    ra, ri = float(p["rail_mass"]), float(p["rail_rotary_inertia"])
    roots = np.roots([ei, -omega**2 * (ri + ei * ra / kga), ra * omega**2 * (ri * omega**2 / kga
                                                                              - 1)]).real
    return math.sqrt(roots.max()), math.sqrt(-roots.min())


@pytest.mark.parametrize("freq", [100.0, 500.0])
def test_floquet_waves_of_the_free_rail_are_the_timoshenko_waves(freq):
    """Without pads, one bay's Floquet multipliers are exp(+-i k L_S) and exp(+-k' L_S) of the
    Timoshenko beam: (lambda + 1/lambda) / 2 = cos(k L_S) and cosh(k' L_S), to the FE
    dispersion error ((k L_e)^4 scale: 1e-6 at 100 Hz, 6e-5 at 500 Hz)."""
    track = wfjax.Track()
    p = dict(track_numbers(track), pad_stiffness=0.0, pad_damping=0.0, ballast_gap=0.0)
    k, m, c, _ = P._cell_matrices(p, int(track.elements_per_bay))
    w = 2 * math.pi * freq
    lam = P._waves(P._condensed(k - w**2 * m + 1j * w * c))[0]
    half = np.sort(((lam + 1 / lam) / 2).real)
    kp, ke = _dispersion(p, w)
    np.testing.assert_allclose(half[:2], math.cos(kp * LS), atol=1e-4)
    np.testing.assert_allclose(half[2:], math.cosh(ke * LS), rtol=1e-4)


def test_floquet_multipliers_come_in_reciprocal_pairs_and_decay():
    """lambda and 1/lambda (a reciprocal structure: the waves' eigenproblem finds all four,
    which the reduction's pair and its reciprocals must equal), none on the unit circle with
    damping; the least decay per bay at the pinned-pinned resonance (0.0011 Np at 943 Hz
    against 0.5 Np at 300 Hz): why no finite track converges there."""
    lam = P.floquet_multipliers(wfjax.Track(), [300.0, 943.3])
    p, ne = track_numbers(wfjax.Track()), int(wfjax.Track().elements_per_bay)
    k, m, c, _ = P._cell_matrices({**p, "ballast_gap": 0.0}, ne)
    for f, got in zip((300.0, 943.3), lam, strict=True):
        w = 2 * math.pi * f
        waves = P._waves(P._condensed(k - w * w * m + 1j * w * c))[0]
        np.testing.assert_allclose(got, waves[np.argsort(np.abs(waves))], rtol=1e-7)
    assert np.all(np.abs(lam[:, :2]) < 1) and np.all(np.abs(lam[:, 2:]) > 1)
    decay = -np.log(np.abs(lam[:, 1]))  # the slower wave
    assert decay[0] > 0.1 and decay[1] < 0.003


def test_the_slower_multiplier_is_the_receptances_decay_along_the_rail():
    """At 1361.5 Hz two waves decay alike and the waves' eigenproblem gave 0.926 for the
    slower (and 2e-5 for the faster, 0.070): 20 bays from the load only the slower wave is
    left, and the infinite track's receptance decays by its multiplier from bay to bay."""
    h = T.periodic_receptance(wfjax.Track(), [1361.5], 0.3, 0.3 + LS * np.array([20, 21]))[0]
    lam = P.floquet_multipliers(wfjax.Track(), [1361.5])[0]
    assert abs(h[1] / h[0]) == pytest.approx(abs(lam[1]), rel=1e-6)
    assert abs(lam[0]) == pytest.approx(0.0696, rel=1e-3)


def test_periodic_receptance_equals_a_long_finite_track_away_from_pinned_pinned():
    """Away from the pinned-pinned band, a 400-bay clamped track (direct sparse FE solve) is
    converged in length: the periodic receptance equals it, point and transfer, statics
    included. At 1361.5 Hz two Floquet waves decay alike: the boundary stiffnesses from
    their eigenvectors were 1.3 % off there."""
    f = np.array([0.0, 20.0, 111.0, 285.0, 600.0, 1361.5, 1500.0, 2000.0])
    long = wfjax.Track(ends="absorbing", n_bays=400)
    for x, xr in ((0.0, None), (LS / 2, None), (0.3, np.array([1.0, -0.45]))):
        h = T.periodic_receptance(wfjax.Track(), f, x, xr)
        ref = T.receptance(long, f, x, xr)
        np.testing.assert_allclose(h, ref, rtol=1e-5)


def test_periodic_receptance_where_the_floquet_eigenvectors_failed():
    """At 5934.6 Hz the eigenvector form of the boundary stiffnesses was a factor 5 off. A
    slow wave there keeps finite tracks from converging (200 to 1600 bays move the point
    receptance by 1.5 %): the infinite track's lies within 2 % of 800 and 1600 bays'."""
    h = T.periodic_receptance(wfjax.Track(), [5934.6], 0.0)
    for n in (800, 1600):
        long = wfjax.Track(ends="absorbing", n_bays=n)
        np.testing.assert_allclose(h, T.receptance(long, [5934.6], 0.0),
                                   rtol=0.02)


def test_periodic_receptance_refuses_a_non_finite_position():
    with pytest.raises(ValueError, match="x_response=.*nan"):
        T.periodic_receptance(wfjax.Track(), [100.0], 0.0, np.array([0.3, np.nan]))


def test_periodic_receptance_refuses_varying_supports():
    pads = np.full(23, 120e6)
    pads[5] = 60e6
    with pytest.raises(ValueError, match="pad_stiffness varies"):
        T.periodic_receptance(wfjax.Track(n_bays=24, pad_stiffness=pads), [100.0])


@pytest.mark.slow
def test_finite_tracks_approach_the_periodic_receptance_at_pinned_pinned():
    """In 900-990 Hz the finite clamped track's midspan receptance approaches the infinite
    track's as it lengthens (its slow waves decay 0.0011 Np per bay): largest difference
    85 % at 140 bays, 35 % at 400, 6 % at 800 (benchmarks/receptance_length.py)."""
    f = np.linspace(900.0, 990.0, 91)
    h = T.periodic_receptance(wfjax.Track(), f, LS / 2)
    finite = [T.receptance(wfjax.Track(ends="absorbing", n_bays=n), f, LS / 2)
              for n in (140, 400, 800)]
    err = [np.max(np.abs(hn - h) / np.abs(h)) for hn in finite]
    assert err[0] > err[1] > err[2]
    assert err[2] < 0.1


def test_boundary_stiffness_batched_over_frequency_is_each_frequencys():
    """The cyclic reduction batched over frequencies (each chain stopping where it converged)
    equals it run at each frequency alone, across the pinned-pinned band edge and the close
    multipliers at 1361.5 Hz."""
    track = wfjax.Track()
    k, m, c, _ = P._cell_matrices(P._numbers(track), int(track.elements_per_bay))
    w = 2 * math.pi * np.array([10.0, 300.0, 943.3, 1361.5, 5000.0, 20000.0])
    cells = k[None] - (w**2)[:, None, None] * m[None] + 1j * w[:, None, None] * c[None]
    batched = P._right_stiffness(P._condensed(cells))
    alone = np.array([P._right_stiffness(P._condensed(cell)) for cell in cells])
    np.testing.assert_allclose(batched, alone, rtol=1e-12, atol=0)

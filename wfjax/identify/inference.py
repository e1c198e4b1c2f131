"""The posterior of every wheel's flat: a grid over (shape, length) x phase, marginalised over
the nuisance realisations of the response table.

Noise model: every reading y_b = mu_b (1 + e_b), e_b ~ N(0, sigma^2) independent, with
sigma^2 = noise^2 + model^2 (``noise``: the detector's relative noise, default 3 %; ``model``:
the emulator's own relative error, default 2 %). The likelihood of a wheel in one passage is

    p(y | shape, l) = 1 / (P R) sum_phase sum_r prod_b N(y_b; mu_b(shape, l, phase, r),
                                                      (sigma mu_b)^2)

(uniform phase over one wheel circumference, the R roughness/support realisations equally
likely); passages of the same wheel multiply. Prior: P(new) = ``p_new``, the rounded shapes
share the rest; length uniform on the grid [0, ``max_length``].
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.special import logsumexp
from scipy.stats import chi2

from . import forward as fwd
from . import prediction

PHASE_REFINE = 4  # phase points per table position interval (linear in between)
# relative standard deviation of a neighbour correction: a neighbour's ringing read by a wheel
# in a gate changes by tens of kN within a few cm of the neighbour's phase (measured: 26
# against 46 kN, 4 cm apart at 100 km/h), finer than a phase mode's representative point
CORRECTION_ERROR = 0.5

__all__ = ["PHASE_REFINE", "Prior", "WheelPosterior", "CorrectionMixture", "loglik_grid",
           "posterior", "weighted_quantile"]


@dataclasses.dataclass(frozen=True)
class CorrectionMixture:
    """The neighbours' effect on one wheel's readings in one passage, uncertain: ``values``
    [M, n_bays] N, each the coupled-minus-alone readings with the neighbours at one
    configuration of their impact phases, and ``weights`` [M] (sum 1) the configurations'
    probabilities under the neighbours' phase posteriors. The likelihood marginalises over
    it: p(y | theta) = sum_m weights_m p(y | theta, values_m). One configuration of weight 1
    is the plain additive correction."""

    weights: np.ndarray
    values: np.ndarray

    @classmethod
    def of(cls, correction) -> CorrectionMixture | None:
        """``correction`` as a mixture: None stays None; an array [n_bays] N is one
        configuration of weight 1."""
        if correction is None or isinstance(correction, cls):
            return correction
        values = np.atleast_2d(np.asarray(correction, float))
        return cls(np.ones(1), values)

    def mode(self) -> np.ndarray:
        """[n_bays] N: the most probable configuration's values."""
        return self.values[int(np.argmax(self.weights))]


@dataclasses.dataclass(frozen=True)
class Prior:
    """Prior and grid: ``p_new`` P(kind = new); lengths 0..``max_length`` [m] in steps of
    ``length_step`` [m] (uniform)."""

    p_new: float = 0.5
    max_length: float = 0.13
    length_step: float = 0.002

    def lengths(self) -> np.ndarray:
        """[n_len] the length grid [m]."""
        return np.arange(0.0, self.max_length + 1e-12, self.length_step)

    def log_shapes(self, shapes) -> np.ndarray:
        """[S] log prior of each (kind, factor) shape."""
        n_round = sum(1 for k, _ in shapes if k == "rounded")
        return np.log([self.p_new if k == "new" else (1 - self.p_new) / n_round
                       for k, _ in shapes])


def loglik_grid(table: fwd.ResponseTable, bays, readings, lengths, sigma: float,
                peak_only: bool = False, correction=None):
    """(log-likelihood [S, n_len, P, R], chi-square tail probability [S, n_len, P, R],
    phases [P] m) of one wheel's ``readings`` [n_bays] N (or [1] its peak when
    ``peak_only``) under the relative Gaussian of total relative standard deviation
    ``sigma``. ``correction``: the neighbours' effect, [n_bays] N added to the prediction,
    or a :class:`CorrectionMixture` over which the likelihood is marginalised (each cell's
    tail probability P(chi2_n > chi2(y)) then averaged with the configurations'
    responsibilities)."""
    phases = prediction.phase_grid(table, bays, PHASE_REFINE)
    mu0 = prediction.predict_refined(table, bays, lengths, PHASE_REFINE)  # [S, L, P, R, n_bays]
    mix = CorrectionMixture.of(correction)
    y = np.asarray(readings, float)
    lls, tails = [], []
    for c in (mix.values if mix is not None else [None]):
        mu = mu0 if c is None else mu0 + c[None, None, None, None, :]
        if peak_only:
            mu = mu.max(axis=-1, keepdims=True)
        sd = sigma * mu if c is None else np.sqrt((sigma * mu) ** 2 + (
            CORRECTION_ERROR * c[None, None, None, None, :]) ** 2)
        c2 = np.sum(((y - mu) / sd) ** 2, axis=-1)
        lls.append(-0.5 * c2 - np.sum(np.log(sd), axis=-1) - 0.5 * y.size * np.log(2 * np.pi))
        tails.append(chi2.sf(c2, y.size))
    if mix is None or len(lls) == 1:
        return lls[0], tails[0], phases
    lw = np.log(np.maximum(np.asarray(mix.weights, float), 1e-300))
    ll = np.stack(lls) + lw[:, None, None, None, None]  # [M, S, L, P, R]
    total = logsumexp(ll, axis=0)
    resp = np.exp(ll - total[None])
    return total, np.sum(resp * np.stack(tails), axis=0), phases


def weighted_quantile(lo, hi, weights, q) -> np.ndarray:
    """Quantiles ``q`` of the mixture of uniform distributions on [``lo``, ``hi``] (every
    grid cell's range) with ``weights``: the grid posterior read as a piecewise-constant
    density, so an interval does not snap to grid points."""
    lo, hi, w = (np.ravel(a) for a in (lo, hi, weights))
    w = w / np.sum(w)
    x = np.unique(np.concatenate([lo, hi]))
    width = np.maximum(hi - lo, 1e-300)
    cdf = np.sum(w[None, :] * np.clip((x[:, None] - lo[None, :]) / width[None, :], 0, 1),
                 axis=1)
    return np.interp(q, cdf, x)


@dataclasses.dataclass
class WheelPosterior:
    """One wheel's posterior on the grid.

    Attributes:
        shapes: [S] (kind, l / l0). lengths: [n_len] m. wheel_radius: R [m].
        weights: [S, n_len] posterior probabilities (sum 1).
        phases: per passage [P] impact coordinates [m]; phase_weights: per passage [P].
        ppc_p: posterior-predictive p-value of the readings' chi-square (every passage).
        best_fit: per passage [n_bays] the readings [N] of the posterior mode.
    """

    shapes: tuple
    lengths: np.ndarray
    wheel_radius: float
    weights: np.ndarray
    phases: list
    phase_weights: list
    ppc_p: float
    best_fit: list
    best: tuple = ()

    def depths(self) -> np.ndarray:
        """[S, n_len] depth [m] of each grid flat."""
        return np.stack([fwd.depth_of(k, self.lengths, f or 1.0, self.wheel_radius)
                         for k, f in self.shapes])

    def p_kind(self, kind: str) -> float:
        """P(kind) (``"new"`` or ``"rounded"``)."""
        return float(sum(self.weights[i].sum() for i, (k, _) in enumerate(self.shapes)
                         if k == kind))

    def p_length_at_least(self, length: float) -> float:
        """P(l >= ``length`` [m])."""
        return float(self.weights[:, self.lengths >= length - 1e-12].sum())

    def cells(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) [n_len] edges [m] of the length grid's cells (the first from 0)."""
        h = np.diff(self.lengths).mean() if self.lengths.size > 1 else 1.0
        return np.maximum(self.lengths - h / 2, 0.0), self.lengths + h / 2

    def length_quantiles(self, q) -> np.ndarray:
        """Length quantiles [m] (the posterior uniform within each grid cell)."""
        lo, hi = self.cells()
        shape = self.weights.shape
        return weighted_quantile(np.broadcast_to(lo, shape), np.broadcast_to(hi, shape),
                                 self.weights, q)

    def depth_quantiles(self, q) -> np.ndarray:
        """Depth quantiles [m] (each length cell mapped to its depth range, uniform)."""
        lo, hi = self.cells()
        d = [np.stack([fwd.depth_of(k, e, f or 1.0, self.wheel_radius) for k, f in
                       self.shapes]) for e in (lo, hi)]
        return weighted_quantile(d[0], d[1], self.weights, q)

    def interval(self, what: str, level: float) -> tuple[float, float]:
        """Central ``level`` interval of ``"length"`` or ``"depth"`` [m]."""
        q = [(1 - level) / 2, (1 + level) / 2]
        lo, hi = (self.length_quantiles if what == "length" else self.depth_quantiles)(q)
        return float(lo), float(hi)

    def phase(self, passage: int = 0) -> tuple[float, float]:
        """(the most probable impact coordinate [m], its posterior probability)."""
        w = self.phase_weights[passage]
        i = int(np.argmax(w))
        return float(self.phases[passage][i]), float(w[i])


def posterior(tables, bays, readings, prior: Prior | None = None, noise: float = 0.03,
              model: float = 0.02, peak_only: bool = False, corrections=None
              ) -> WheelPosterior:
    """The :class:`WheelPosterior` of one wheel seen in passages ``p``: ``tables[p]`` (its
    speed's :class:`~wfjax.identify.forward.ResponseTable`), detector ``bays[p]``,
    ``readings[p]`` [n_bays] N (or [1] peak), ``corrections[p]`` [n_bays] N, a
    :class:`CorrectionMixture` or None."""
    prior = prior or Prior()
    lengths = prior.lengths()
    sigma = float(np.hypot(noise, model))
    total = prior.log_shapes(tables[0].shapes)[:, None] * np.ones(lengths.size)
    parts = []
    for p, table in enumerate(tables):
        corr = None if corrections is None else corrections[p]
        ll, tail, phases = loglik_grid(table, bays[p], readings[p], lengths, sigma,
                                       peak_only, corr)
        n_pr = ll.shape[2] * ll.shape[3]
        total = total + logsumexp(ll, axis=(2, 3)) - np.log(n_pr)
        parts.append((ll, tail, phases))
    w = np.exp(total - logsumexp(total))
    phases, phase_w, p_values, fits = [], [], [], []
    s_best, l_best = np.unravel_index(int(np.argmax(w)), w.shape)
    for p, (ll, tail, ph) in enumerate(parts):
        joint = ll + np.log(np.maximum(w, 1e-300))[:, :, None, None] - (
            logsumexp(ll, axis=(2, 3))[:, :, None, None])
        jw = np.exp(joint - logsumexp(joint))  # [S, L, P, R] posterior of (theta, phase, r)
        phases.append(ph)
        phase_w.append(jw.sum(axis=(0, 1, 3)))
        p_values.append(float(np.sum(jw * tail)))
        i_p = int(np.argmax(jw[s_best, l_best].sum(axis=-1)))
        mu = prediction.predict_refined(tables[p], bays[p], lengths[[l_best]],
                                 PHASE_REFINE)[s_best, 0, i_p]
        mix = None if corrections is None else CorrectionMixture.of(corrections[p])
        mu = mu.mean(axis=0) + (0 if mix is None else mix.mode())
        fits.append(mu.max(keepdims=True) if peak_only else mu)
    best = (tables[0].shapes[s_best], float(lengths[l_best]),
            [float(ph[int(np.argmax(pw))]) for ph, pw in zip(phases, phase_w, strict=True)])
    return WheelPosterior(tables[0].shapes, lengths, tables[0].wheel_radius, w, phases,
                          phase_w, float(min(p_values)), fits, best)

"""Non-reflecting track ends: a fitted passive network that continues the rail beyond each end
of the finite track as the semi-infinite track would (``Track.ends``).

The exact end of a finite track is the semi-infinite track's boundary stiffness K_R(omega)
[2 x 2 on the end node's w, theta] (:mod:`wfjax.model.periodic`, cyclic reduction). A
time-domain model needs it as degrees of freedom: :data:`N_AUX` internal DOFs joined to the end
node, with stiffness, damping and mass matrices K, C, M [(2 + N_AUX)^2] each written as
L L^T (positive semi-definite: the network is passive and cannot destabilise the track), and
K_fit(omega) the Schur complement of K + i omega C - omega^2 M onto the end node. The factors
are fitted to the relative Frobenius error of K_fit against K_R (theta scaled by
:data:`THETA_SCALE`) on 10 Hz-:data:`BAND_TOP`, dense around the pinned-pinned band edge,
and, weighted :data:`HF_WEIGHT`, up to 20 kHz. The left end carries the mirror image
(theta -> -theta).

The default track's network is stored with the package (``end_network_default.json``: 6,000
L-BFGS iterations from a random start, :func:`fit`, ``benchmarks/end_network.py``). Any other
track's is fitted from it on first use (:func:`_fitted`: 5-30 s on 2 cores) and cached on
disk: Levenberg-Marquardt with an analytic Jacobian (:func:`_residuals`) along a path of
tracks from the stored one to it (:func:`_path`), the network's frequencies scaled with the
band edge. A fit must come within :data:`FIT_TOLERANCE` of K_R beside the band edge
(:func:`fit_error`), or the track is refused.
Why and how well (the receptances within 0.6 % of the infinite track's beside +-5 Hz of the
band edge, where clamped or absorbing ends leave 28-63 %): ``docs/convergence.md``, "A fitted
passive end network" and "End networks".
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import pathlib
import warnings

import numpy as np

from .. import _cache
from ..params import Track
from . import periodic as P
from .sleepers import is_periodic, is_uniform

__all__ = ["N_AUX", "FIT_TOLERANCE", "EndsWarning", "network", "resolved", "network_stiffness",
           "boundary_stiffness", "band_edge", "fit", "fit_error", "is_stored", "matrices",
           "stored"]

N_AUX = 24  # the network's internal DOFs per end
THETA_SCALE = 0.1  # m: theta entries scaled to be comparable with w's
_UNITS = np.array([1.0, 1.0 / THETA_SCALE])  # the (w, theta) rows' and columns' scaling
SCALES = (1e8, 1e4, 1.0)  # K [N/m], C [N s/m], M [kg] of a unit factor
BAND_TOP = 2000.0  # [Hz] the top of the fit's band and its tolerance's: the accuracy table's
# receptances end at 2 kHz, and sleepers more than about 0.665 m apart bring a second, sharp
# feature of K_R into 2-2.5 kHz (the slow wave's least decay per bay: 2596 Hz at 0.65 m, 2446
# at 0.68, 2352 at 0.7) that the stored network has no pole for (the stored fit: 10-2500 Hz)
HF_WEIGHT = 0.02  # the fit's weight above BAND_TOP (the impact's band: forces, not receptances)
FIT_TOLERANCE = 0.02  # the fit's largest relative error on 10 Hz-BAND_TOP beside the band edge
EDGE_EXCLUDED = 5.0  # [Hz] either side of the band edge left out of the tolerance (a run's
# window resolves about 1 / T: 20-50 Hz; no finite track resolves the edge's singular peak)
STEP_RATIO = 1.5  # the warm fit's path: the largest factor a track number moves by per step,
SPACING_STEP_RATIO = 1.1  # the sleeper spacing's (it moves the band edge as L_S^-2: sleepers
# 0.5 m apart fit within 1.3 % in 3 steps, and stay at 4.2 % in one)
STEP_ITERATIONS = 8  # Levenberg-Marquardt steps at most per point of the path
STALL = 0.01  # a point of the path is done when a step lowers the cost by less than this
POLISH_ROUNDS = 8  # then rounds of POLISH_ITERATIONS steps on the track itself, each followed
POLISH_ITERATIONS = 5  # by the tolerance's check, before a fit above it is refused
STORED = pathlib.Path(__file__).with_name("end_network_default.json")
FIT_KEY = {"n_aux": N_AUX, "tolerance": FIT_TOLERANCE, "hf_weight": HF_WEIGHT,
           "band_top": BAND_TOP, "scheme": 4}
"""What a fitted network's cache entries (its own and its track's modal model) are keyed by
beside the track's numbers: a change of the fit's procedure refits."""


def _lowers(factors, n: int = N_AUX + 2, xp=np) -> list:
    """The three lower-triangular factors [n, n] (L_K, L_C, L_M) stacked in ``factors``."""
    tri = np.tril_indices(n)
    nt = tri[0].size
    if xp is np:
        out = [np.zeros((n, n)) for _ in SCALES]
        for i, lower in enumerate(out):
            lower[tri] = factors[i * nt:(i + 1) * nt]
        return out
    return [xp.zeros((n, n)).at[tri].set(factors[i * nt:(i + 1) * nt])
            for i in range(len(SCALES))]


def matrices(factors, n: int = N_AUX + 2, xp=np):
    """(K [N/m], C [N s/m], M [kg]) [n, n] of the network from its stacked lower-triangular
    factors ``factors`` [3 n (n + 1) / 2] (L_K, L_C, L_M): each ``SCALES[i] L L^T``."""
    lowers = _lowers(factors, n, xp)
    return tuple(s * lower @ lower.T for s, lower in zip(SCALES, lowers, strict=True))


def network_stiffness(mats, w, xp=np):
    """[n_f, 2, 2] the network's dynamic stiffness at its end node [N/m, N, N m], at angular
    frequencies ``w`` [n_f] [rad/s], from its ``(K, C, M)``."""
    k, c, m = mats
    s = k[None] + 1j * w[:, None, None] * c[None] - (w**2)[:, None, None] * m[None]
    return s[:, :2, :2] - s[:, :2, 2:] @ xp.linalg.solve(s[:, 2:, 2:], s[:, 2:, :2])


def boundary_stiffness(track: Track, f) -> np.ndarray:
    """[n_f, 2, 2] the right semi-infinite track's boundary stiffness at ``f`` [Hz]: the force
    at its first node (a sleeper's, the sleeper included) that holds it at u_0."""
    k, m, c, _ = P._cell_matrices(P._numbers(track), int(track.elements_per_bay))
    w = 2 * math.pi * np.atleast_1d(np.asarray(f, dtype=float))[:, None, None]
    return P._right_stiffness(P._condensed(k - w * w * m + 1j * w * c))


@functools.lru_cache(maxsize=16)
def _band_edge(key: tuple) -> float:
    track = Track(**dict(key))
    scale = float(track.sleeper_spacing) / 0.65  # the same places in the bays as on 0.65 m
    f = np.arange(800.0, 1300.0, 1.0) / scale**2
    for step in (0.01, 1e-4):  # refine around the peak (within one step of the coarse grid)
        peak = f[np.argmax(np.abs(P.periodic_receptance(track, f, 0.3 * scale, 1.0 * scale)))]
        f = peak + np.arange(-100, 100) * step
    return float(f[np.argmax(np.abs(P.periodic_receptance(track, f, 0.3 * scale,
                                                           1.0 * scale)))])


def band_edge(track: Track) -> float:
    """[Hz] the pinned-pinned band edge: where the infinite track's transfer receptance
    0.3 -> 1.0 m peaks (positions scaled with the sleeper spacing L_S / 0.65 m, so that they
    keep their places in the bays: with fixed positions sleepers 0.5 m apart peaked at the
    search's lower end, 1351 Hz, not at their edge, 1419 Hz), the rail's pinned-pinned wave
    stops travelling and |H| grows as |f - f_edge|^-1/2 (943.32 Hz on the default track)."""
    return _band_edge(_key(track))


def _key(track: Track) -> tuple:
    p = P._numbers(track)
    return tuple(sorted({**{k: float(v) for k, v in p.items()},
                         "elements_per_bay": int(track.elements_per_bay)}.items()))


def _grid(edge: float) -> tuple[np.ndarray, np.ndarray]:
    """The fit's frequencies [Hz] (10 Hz-:data:`BAND_TOP`, 0.25 Hz steps within 50 Hz of
    ``edge``, then to 20 kHz) and their weights."""
    near = np.concatenate([np.arange(-243, -43, 1.0), np.arange(-43, 57, 0.25),
                           np.arange(57, 357, 1.0)]) + edge
    band = np.unique(np.concatenate([np.geomspace(10, near[0], 150), near,
                                     np.geomspace(near[-1], BAND_TOP, 100)]))
    f = np.unique(np.concatenate([band, np.geomspace(BAND_TOP, 20000, 300)[1:]]))
    return f, np.where(f <= BAND_TOP, 1.0, HF_WEIGHT)


def _relative_error(track: Track, f):
    """A function of the factors: the relative Frobenius error [n_f] of the network's
    stiffness against the track's K_R at ``f`` [Hz] (jax)."""
    import jax.numpy as jnp

    t = np.diag(_UNITS)
    target = np.einsum("ij,fjk,kl->fil", t, boundary_stiffness(track, f), t)
    norm = jnp.asarray(np.linalg.norm(target, axis=(1, 2)))
    w = jnp.asarray(2 * np.pi * f)

    def rel_err(x):
        kf = jnp.einsum("ij,fjk,kl->fil", t,
                        network_stiffness(matrices(x, xp=jnp), w, xp=jnp), t)
        return jnp.sqrt(jnp.sum(jnp.abs(kf - target) ** 2, axis=(1, 2))) / norm

    return rel_err


def _error_of(track: Track):
    """``factors -> `` the network's largest relative error against ``track``'s K_R on
    10 Hz-:data:`BAND_TOP`, leaving out +-``EDGE_EXCLUDED`` Hz around the band edge (K_R
    computed once)."""
    edge = band_edge(track)
    f = np.unique(np.concatenate([np.geomspace(10, BAND_TOP, 600),
                                  edge + np.arange(-100, 100.01, 0.25)]))
    f = f[f <= BAND_TOP]
    rel_err = _relative_error(track, f[np.abs(f - edge) > EDGE_EXCLUDED])
    return lambda factors: float(np.max(np.asarray(rel_err(np.asarray(factors)))))


def fit_error(track: Track, factors) -> float:
    """The network's largest relative error against K_R on 10 Hz-:data:`BAND_TOP`, leaving out
    +-``EDGE_EXCLUDED`` Hz around the band edge (what :data:`FIT_TOLERANCE` bounds)."""
    return _error_of(track)(factors)


def _fitter(track: Track):
    """``(start, iterations) -> factors``: L-BFGS on ``track``'s K_R, its targets and compiled
    objective built once for every round."""
    import jax
    import jax.numpy as jnp
    import scipy.optimize

    f, weight = _grid(band_edge(track))
    rel_err, weight = _relative_error(track, f), jnp.asarray(weight)
    value_grad = jax.jit(jax.value_and_grad(
        lambda x: jnp.sum(weight * rel_err(x) ** 2) / jnp.sum(weight)))

    def run(start, iterations: int) -> np.ndarray:
        res = scipy.optimize.minimize(lambda x: tuple(np.asarray(v) for v in value_grad(x)),
                                      np.asarray(start, dtype=float), jac=True,
                                      method="L-BFGS-B",
                                      options={"maxiter": int(iterations), "maxcor": 50,
                                               "ftol": 1e-15, "gtol": 1e-12})
        return np.asarray(res.x)

    return run


def fit(track: Track, start, iterations: int):
    """Factors [3 n (n + 1) / 2] of the network fitted to ``track``'s K_R from ``start``
    (factors), at most ``iterations`` L-BFGS iterations: the fit from a random start that
    made the stored network (L-BFGS finds its way from afar, where Levenberg-Marquardt
    stalls; the warm fits of :func:`network` are Levenberg-Marquardt's)."""
    return _fitter(track)(start, iterations)


@functools.cache
def stored() -> dict:
    """The stored default network: ``factors``, the ``track`` numbers it was fitted to (with
    ``elements_per_bay``) and its fit's figures."""
    return json.loads(STORED.read_text())


_ENTRIES = ((0, 0, 1.0), (1, 1, 1.0), (0, 1, math.sqrt(2.0)))  # a symmetric 2 x 2's
# independent entries, weighted so that their squares sum to its squared Frobenius norm


def _problem(track: Track, edge: float) -> tuple:
    """``track``'s K_R on the fit's grid around ``edge`` [Hz]: (omega [n_f] [rad/s], the
    scaled targets [n_f, 2, 2], each frequency's residual weight sqrt(w_f) / |K_R| [n_f])."""
    f, weight = _grid(edge)
    target = boundary_stiffness(track, f) * np.outer(_UNITS, _UNITS)
    return 2 * np.pi * f, target, np.sqrt(weight) / np.linalg.norm(target, axis=(1, 2))


def _residuals(factors, problem, jacobian: bool = True):
    """The fit's residuals [6 n_f] (real and imaginary parts of the scaled entries of
    K_fit - K_R, weighted as :func:`_relative_error`'s squared sum) and, if ``jacobian``,
    their derivatives [6 n_f, 3 n_t] in the factors.

    With S = K + i omega C - omega^2 M and X = S_aa^-1 S_ae (a: internal, e: end node),
    K_fit = P^T S P for P = [I; -X] (complex symmetric, no conjugate), and dK_fit = P^T dS P:
    S P vanishes on the internal rows, so X's change drops out. A factor entry L_ij moves
    S by s (e_i L_j^T + L_j e_i^T) (L_j the j-th column of L^T), so K_fit by
    s (p_i u_j^T + u_j p_i^T) with p = P's rows and u = (L^T P)'s: no solve per parameter."""
    w, target, weight = problem
    lowers = _lowers(factors)
    k, c, m = (s * lower @ lower.T for s, lower in zip(SCALES, lowers, strict=True))
    dyn = k[None] + 1j * w[:, None, None] * c[None] - (w**2)[:, None, None] * m[None]
    x = np.linalg.solve(dyn[:, 2:, 2:], dyn[:, 2:, :2])
    diff = (dyn[:, :2, :2] - dyn[:, :2, 2:] @ x) * np.outer(_UNITS, _UNITS) - target
    gains = np.array([g for _, _, g in _ENTRIES]) * weight[:, None]
    r = np.stack([diff[:, a, b] for a, b, _ in _ENTRIES], axis=1) * gains
    r = np.concatenate([r.real.ravel(), r.imag.ravel()])
    if not jacobian:
        return r
    p = np.concatenate([np.broadcast_to(np.eye(2), x.shape[:1] + (2, 2)), -x], axis=1)
    rows, cols = np.tril_indices(N_AUX + 2)
    scaled = np.array([_UNITS[a] * _UNITS[b] for a, b, _ in _ENTRIES]) * gains
    blocks = []
    for s, lower, along in zip(SCALES, lowers, (np.ones_like(w), 1j * w, -w * w),
                                  strict=True):
        u = np.einsum("ji,fjk->fik", lower, p)
        pi, uj = p[:, rows], u[:, cols]
        d = np.stack([pi[..., a] * uj[..., b] + uj[..., a] * pi[..., b]
                      for a, b, _ in _ENTRIES], axis=1)
        blocks.append(d * (s * along[:, None, None] * scaled[..., None]))
    jac = np.concatenate(blocks, axis=2).reshape(r.size // 2, -1)
    return r, np.concatenate([jac.real, jac.imag])


def _levenberg_marquardt(factors, problem, iterations: int, stall: float = 0.0) -> np.ndarray:
    """At most ``iterations`` accepted Levenberg-Marquardt steps (Marquardt's scaling by the
    normal matrix's diagonal) on :func:`_residuals` from ``factors``; stops when a step
    lowers the cost by less than the fraction ``stall``, or no step lowers it."""
    x = np.asarray(factors, dtype=float)
    r, jac = _residuals(x, problem)
    cost, damping = r @ r, 1e-3
    for _ in range(iterations):
        grad, normal = jac.T @ r, jac.T @ jac
        diag = np.diag(np.diag(normal) + 1e-300)
        while damping < 1e12:
            step = np.linalg.solve(normal + damping * diag, -grad)
            trial = _residuals(x + step, problem, jacobian=False)
            if trial @ trial < cost:
                break
            damping *= 4
        else:
            return x
        x, damping, before, cost = x + step, max(damping / 3, 1e-12), cost, trial @ trial
        if cost > (1 - stall) * before:
            return x
        r, jac = _residuals(x, problem)
    return x


def _path(track: Track) -> list[Track]:
    """The tracks a warm fit passes through, from the stored network's to ``track`` (its
    mesh throughout): every number moved geometrically, none by more than
    :data:`STEP_RATIO` per step (the sleeper spacing :data:`SPACING_STEP_RATIO`)."""
    start, goal = stored()["track"], dict(_key(track))
    ratios = {k: goal[k] / start[k] for k in goal
              if k != "elements_per_bay" and start[k] > 0 and goal[k] > 0}
    limits = {k: SPACING_STEP_RATIO if k == "sleeper_spacing" else STEP_RATIO for k in ratios}
    steps = max([1] + [math.ceil(abs(math.log(r)) / math.log(limits[k]) - 1e-9)
                       for k, r in ratios.items()])
    return [Track(**{**goal, **{k: start[k] * r ** (i / steps) for k, r in ratios.items()}})
            for i in range(1, steps)] + [Track(**goal)]


def _fitted(track: Track) -> dict:
    """``{"factors", "error"}``: ``track``'s network fitted from the stored one along
    :func:`_path` (each point a few Levenberg-Marquardt steps), the frequencies scaled with the
    band edge, then polished on ``track`` until within :data:`FIT_TOLERANCE` or for
    :data:`POLISH_ROUNDS` rounds; its error (:func:`fit_error`; kept on disk either way, so
    that a refused track is not refitted in every process)."""
    x = np.asarray(stored()["factors"], dtype=float)
    edge, error, path = band_edge(track), _error_of(track), _path(track)
    first = float(stored()["band_edge_Hz"])
    nt, edges = x.size // 3, first * (edge / first) ** (np.arange(len(path) + 1) / len(path))
    edges[-1] = edge
    for point, before, at in zip(path, edges[:-1], edges[1:], strict=True):
        x[nt:2 * nt] /= math.sqrt(at / before)  # C / beta and M / beta^2: K(omega / beta)
        x[2 * nt:] /= at / before
        problem = _problem(point, at)  # the last point is the track itself, at its edge
        x = _levenberg_marquardt(x, problem, STEP_ITERATIONS, STALL)
    for _ in range(POLISH_ROUNDS):
        if error(x) <= FIT_TOLERANCE:
            break
        x = _levenberg_marquardt(x, problem, POLISH_ITERATIONS)
    return {"factors": x, "error": np.asarray(error(x))}


def is_stored(track: Track) -> bool:
    """Whether ``track``'s rail, supports and mesh are those of the stored network."""
    return dict(_key(track)) == stored()["track"]


def network(track: Track, cache_dir=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(K [N/m], C [N s/m], M [kg]) [N_AUX + 2]^2 of the right end's network of ``track`` (its
    first two DOFs the end node's w, theta): the stored default's when the track's rail,
    supports and mesh are the default's, else fitted from it and cached on disk.

    Raises ValueError for per-sleeper supports (no semi-infinite continuation to fit) and for
    a fit that stays above :data:`FIT_TOLERANCE`."""
    if not is_uniform(track):
        raise ValueError("Track.ends='network' needs the same supports at every sleeper (a "
                         "per-sleeper track has no semi-infinite continuation to fit): use "
                         "ends='absorbing'")
    if is_stored(track):
        return matrices(np.asarray(stored()["factors"], dtype=float))
    key = dict(_key(track))
    arrays = _cache.load_or_build("end-network", {**key, **FIT_KEY}, lambda: _fitted(track),
                                  cache_dir)
    error = float(arrays["error"])
    if error > FIT_TOLERANCE:
        raise ValueError(
            f"Track.ends='network': no passive network within {FIT_TOLERANCE:.0%} of this "
            f"track's semi-infinite continuation ({error:.1%} after fitting from the "
            "default's): use ends='absorbing'")
    return matrices(np.asarray(arrays["factors"], dtype=float))


def resolved(track: Track) -> Track:
    """``track`` with its ends decided (``Track.ends``): ``"network"`` (``absorbing_sleepers``
    0) or ``"absorbing"``. ``"auto"`` is a network where the supports are the same at every
    sleeper and bonded (``ballast_gap`` 0: a hanging sleeper's one-sided ballast has no linear
    continuation) and the network's fit comes within :data:`FIT_TOLERANCE` (a one-line
    :class:`EndsWarning` otherwise, once per track and process); else absorbing ends."""
    if track.ends == "absorbing":
        return track
    if track.ends == "network":
        return dataclasses.replace(track, absorbing_sleepers=0) if track.absorbing_sleepers \
            else track
    if not is_periodic(track):
        return dataclasses.replace(track, ends="absorbing")
    return dataclasses.replace(track, **_auto(_key(track)))


class EndsWarning(UserWarning):
    """``Track.ends="auto"`` chose absorbing ends for a uniform track: no network fitted."""


@functools.lru_cache(maxsize=64)
def _auto(key: tuple) -> dict:
    """The fields ``"auto"`` ends resolve to on the uniform, bonded track of ``key``."""
    try:
        network(Track(**dict(key)))
    except ValueError as err:
        warnings.warn(f"{err}; this run uses absorbing ends", EndsWarning, stacklevel=3)
        return {"ends": "absorbing"}
    return {"ends": "network", "absorbing_sleepers": 0}

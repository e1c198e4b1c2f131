"""Moving Green's functions of the rail (the paper's Eq. 5) tabulated from the modal model, and an
independent Newmark integration of the full FE track as their reference. The time loop itself
uses the modal states; these tables are for inspection, the paper's figures and checks."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.csgraph
import scipy.sparse.linalg

from ..params import Track
from .fe import assemble, load_vector
from .track import (
    ModalModel,
    check_positive_scalar,
    modal_model,
    mode_shapes_at,
    residual_compliance_at,
)


# --------------------------------------------------------------------------------------------
# moving Green's functions
# --------------------------------------------------------------------------------------------
class MovingGreens(NamedTuple):
    """Moving Green's functions of the rail (Eq. 5).

    Fields:
        t: float [n_t] times t_n = n dt [s] (t_0 = 0).
        x0: float [n_x0] excitation positions [m] (0 = above the middle sleeper).
        g: float [n_x0, n_t] rail displacement at x0 + v t_n per unit impulse at x0 at t = 0
            [m/(N s)] (the dynamic part: the kept modes).
        residual: float [n_x0] static compliance [m/N] of the truncated modes at x0: the
            complete response to a force history is
            xi_R(t) = int_0^t F(tau) g^{v tau}(t - tau) dtau + residual(x(t)) F(t).
        speed: v [m/s].
    """

    t: np.ndarray
    x0: np.ndarray
    g: np.ndarray
    residual: np.ndarray
    speed: float


def default_duration(track: Track) -> float:
    """Default truncation length of the moving Green's functions [s].

    0.1 s. The response decays to about 1 % of its peak within 20-40 ms; what is left is a
    lightly damped ringing of the rail (see the benchmark README) that stays at 0.1-1 % of
    the peak. Comparing 70 and 140 bays shows that this tail is not a reflection from the
    clamped ends (the difference is < 0.5 % of the peak over 0.1 s). The time loop itself
    uses the modal states (no truncation); this length only matters for tabulated g.
    """
    return 0.1


def _check_x0(track: Track, x0) -> np.ndarray:
    ls = float(track.sleeper_spacing)
    if x0 is None:
        return np.linspace(0.0, ls, 27)
    x0 = np.atleast_1d(np.asarray(x0, dtype=float))
    half = (int(track.n_bays) // 2 - 1) * ls
    if x0.ndim != 1 or not np.all(np.isfinite(x0)) or np.any(np.abs(x0) > half):
        raise ValueError(f"x0 must be finite positions within [-{half:g}, {half:g}] m, "
                         f"got {x0!r}")
    return x0


def _time_grid(duration, dt) -> np.ndarray:
    duration = check_positive_scalar("duration", duration, "s")
    dt = check_positive_scalar("dt", dt, "s")
    if dt > duration:
        raise ValueError(f"dt must be <= duration ({duration:g} s), got {dt!r} s")
    return np.arange(int(round(duration / dt)) + 1) * dt


@jax.jit
def _modal_greens(model: ModalModel, x0, t, speed):
    """g [n_x0, n_t]; time in chunks of 1024 samples to bound memory (n_t x n_modes)."""
    chunk = 1024
    n_t = t.shape[0]
    n_c = -(-n_t // chunk)
    tc = jnp.pad(t, (0, n_c * chunk - n_t), mode="edge").reshape(n_c, chunk)

    def one(x):
        phi0 = model.weights * mode_shapes_at(model, x)  # [m]

        def part(tt):
            phit = mode_shapes_at(model, x + speed * tt)  # [chunk, m]
            return jnp.real(jnp.sum(phi0 * phit * jnp.exp(model.poles[None, :] * tt[:, None]),
                                    axis=-1))

        return jax.lax.map(part, tc).reshape(-1)[:n_t]

    return jax.lax.map(one, x0)


def moving_greens(track: Track, speed: float, x0=None, duration: float | None = None,
                  dt: float = 2.5e-5, model: ModalModel | None = None,
                  max_frequency: float = 20e3, cache_dir=None) -> MovingGreens:
    """Moving Green's functions g(x0, t) from the complex-mode model (Eq. 5).

    g(x0, t_n) = Re sum_r w_r phi_r(x0 + v t_n) phi_r(x0) exp(lambda_r t_n), the rail
    displacement at the point moving with the wheel due to a unit impulse at x0 at t = 0.
    The modes above ``max_frequency`` enter as the static term ``residual`` (see
    :class:`MovingGreens`).

    Args:
        track: track parameters.
        speed: train speed v [m/s] (> 0).
        x0: [n_x0] excitation positions [m]; default 27 points across the central bay
            [0, L_S] (2.5 cm apart).
        duration: truncation length [s] (default :func:`default_duration`, 0.1 s).
        dt: sampling time step [s] (default 25 us).
        model: a precomputed :func:`modal_model` (default: built / loaded from the cache).
        max_frequency, cache_dir: passed to :func:`modal_model`.

    Returns:
        :class:`MovingGreens` (numpy arrays).
    """
    speed = check_positive_scalar("speed", speed, "m/s")
    x0 = _check_x0(track, x0)
    t = _time_grid(default_duration(track) if duration is None else duration, dt)
    if np.max(x0) + speed * t[-1] > float(track.n_bays // 2 - 1) * float(track.sleeper_spacing):
        raise ValueError(f"speed * duration = {speed * t[-1]:.2f} m runs off the "
                         f"{track.n_bays}-bay track; shorten duration or add bays")
    if model is None:
        model = modal_model(track, max_frequency, cache_dir)
    g = np.asarray(_modal_greens(model, jnp.asarray(x0), jnp.asarray(t), speed))
    res = np.asarray(residual_compliance_at(model, jnp.asarray(x0)))
    return MovingGreens(t, x0, g, res, speed)


def moving_greens_newmark(track: Track, speed: float, x0, duration: float, dt: float = 2.5e-5,
                          substeps: int = 10) -> MovingGreens:
    """Moving Green's functions by direct time integration of the full FE model (reference).

    Newmark average-acceleration (trapezoidal) integration of M q'' + C q' + K q = 0 from
    q(0) = 0, q'(0) = M^-1 N(x0) (the unit impulse at x0), with step dt / substeps, observed
    at x0 + v t_n through the element shape functions. Independent of the modal route (no
    eigenvectors, no truncation). Its period error is (omega h)^2 / 12.

    Args: as :func:`moving_greens`; ``substeps`` (>= 1) integration steps per output step.

    Returns:
        :class:`MovingGreens` with ``residual`` zero (all modes are in ``g``).
    """
    speed = check_positive_scalar("speed", speed, "m/s")
    x0 = _check_x0(track, x0)
    t = _time_grid(duration, dt)
    if not isinstance(substeps, (int, np.integer)) or substeps < 1:
        raise ValueError(f"substeps must be an integer >= 1, got {substeps!r}")
    fe = assemble(track)
    k, m, c = fe.stiffness, fe.mass, fe.damping
    h = dt / substeps
    lu = scipy.sparse.linalg.splu((k + (2 / h) * c + (4 / h**2) * m).tocsc())
    lu_m = scipy.sparse.linalg.splu(m.tocsc())
    g = np.zeros((x0.size, t.size))
    for i, xi in enumerate(x0):
        obs = load_vector(fe, xi + speed * t)  # [n_dof, n_t]
        q = np.zeros(k.shape[0])
        v = lu_m.solve(load_vector(fe, xi).toarray()[:, 0])
        a = lu_m.solve(-(c @ v))
        hist = np.zeros((t.size, q.size))
        for n in range(1, t.size):
            for _ in range(substeps):
                rhs = m @ ((4 / h**2) * q + (4 / h) * v + a) + c @ ((2 / h) * q + v)
                q_new = lu.solve(rhs)
                v_new = (2 / h) * (q_new - q) - v
                a = (4 / h**2) * (q_new - q) - (4 / h) * v - a
                q, v = q_new, v_new
            hist[n] = q
        g[i] = np.asarray(obs.multiply(hist.T).sum(axis=0)).ravel()
    return MovingGreens(t, x0, g, np.zeros(x0.size), speed)

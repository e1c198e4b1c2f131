"""Complex (state-space) modes of damped linear systems, and their exact discrete-time update.

Shared by :mod:`wfjax.model.wheel` and :mod:`wfjax.model.track`.

For ``M q'' + C q' + K q = f`` with symmetric M, C, K the first-order form
``A z' = B z + [f; 0]`` with ``z = [q; q']``, ``A = [[C, M], [M, 0]]``, ``B = [[-K, 0], [0, M]]``
has eigenpairs ``lambda_r``, ``psi_r = [u_r; lambda_r u_r]``. Normalising
``psi_r^T A psi_r = u_r^T (2 lambda_r M + C) u_r = 1`` (plain transpose, not Hermitian) gives
the modal expansion of the impulse response matrix (e.g. Veletsos & Ventura 1986;
Foss 1958)::

    h(t) = sum_r u_r u_r^T exp(lambda_r t),      H(s) = sum_r u_r u_r^T / (s - lambda_r).

Complex modes come in conjugate pairs; we keep one representative (Im lambda > 0) with weight
2 and take the real part, and keep real (overdamped) poles with weight 1.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import scipy.linalg

__all__ = ["complex_modes", "discrete_step_coefficients", "real_times_complex"]


def complex_modes(stiffness_diag: np.ndarray, damping: np.ndarray, rel_tol: float = 1e-9):
    """Complex modes of ``eta'' + C eta' + diag(w2) eta = g`` (mass-normalised modal space).

    Args:
        stiffness_diag: [n] squared undamped circular frequencies omega_r^2 [rad^2/s^2].
        damping: [n, n] modal damping matrix Phi^T C Phi [1/s] (symmetric, any coupling).
        rel_tol: poles with ``|Im lambda| <= rel_tol * |lambda|`` are treated as real.

    Returns:
        ``(poles, weights, vectors)``: poles [m] complex [rad/s] (Im >= 0), weights [m]
        (2.0 for pair representatives, 1.0 for real poles), vectors [n, m] complex, normalised
        so that the modal-space impulse response is ``Re sum_r w_r a_r a_r^T exp(lambda_r t)``.
    """
    w2 = np.asarray(stiffness_diag, dtype=float)
    c = np.asarray(damping, dtype=float)
    n = w2.size
    a = np.zeros((2 * n, 2 * n))
    a[:n, n:] = np.eye(n)
    a[n:, :n] = -np.diag(w2)
    a[n:, n:] = -c
    lam, vec = scipy.linalg.eig(a, overwrite_a=True, check_finite=False)
    u = vec[:n]
    is_real = np.abs(lam.imag) <= rel_tol * np.maximum(np.abs(lam), 1e-300)
    keep = is_real | (lam.imag > 0)
    lam, u, is_real = lam[keep], u[:, keep], is_real[keep]
    lam = np.where(is_real, lam.real + 0j, lam)
    u = np.where(is_real[None, :], u.real + 0j, u)
    norm = 2.0 * lam * (u * u).sum(axis=0) + (u * real_times_complex(c, u)).sum(axis=0)
    u = u / np.sqrt(norm.astype(complex))[None, :]
    order = np.argsort(np.abs(lam))
    weights = np.where(is_real, 1.0, 2.0)
    return lam[order], weights[order], u[:, order]


def real_times_complex(r: np.ndarray, z: np.ndarray) -> np.ndarray:
    """``r @ z`` for real ``r`` and complex ``z`` as two real products (half the flops of
    the complex product NumPy would form)."""
    return r @ z.real + 1j * (r @ z.imag)


def _series(z, coeffs):
    out = jnp.zeros_like(z)
    for c in reversed(coeffs):
        out = out * z + c
    return out


def discrete_step_coefficients(poles, dt):
    """Exact first-order-hold update of ``q' = lambda q + u(t)``.

    With ``u`` linear within each step, ``u(t) = u_{n-1} (1 - s/dt) + u_n s/dt``::

        q_n = e^{lambda dt} q_{n-1} + a_prev u_{n-1} + a_now u_n,
        a_now  = dt (e^z - 1 - z) / z^2,     a_prev = dt (e^z (z - 1) + 1) / z^2,   z = lambda dt.

    Small ``|z|`` uses the Taylor series (no cancellation). Pure ``jax.numpy``.

    Args:
        poles: complex poles lambda [rad/s], any shape.
        dt: time step [s] (scalar > 0).

    Returns:
        ``(decay, a_prev, a_now)``, each complex with the shape of ``poles``; ``a_*`` in s.
    """
    z = jnp.asarray(poles) * dt
    small = jnp.abs(z) < 1e-2
    zs = jnp.where(small, 1.0, z)  # safe denominator
    e = jnp.exp(z)
    now_exact = (jnp.exp(zs) - 1.0 - zs) / zs**2
    prev_exact = (jnp.exp(zs) * (zs - 1.0) + 1.0) / zs**2
    # sum_{m>=2} z^{m-2}/m!  and  sum_{m>=2} z^{m-2} (m-1)/m!
    fact = [1.0 / np.prod(np.arange(1, m + 1)) for m in range(2, 10)]
    now_series = _series(z, fact)
    prev_series = _series(z, [(m - 1) * f for m, f in zip(range(2, 10), fact, strict=True)])
    a_now = dt * jnp.where(small, now_series, now_exact)
    a_prev = dt * jnp.where(small, prev_series, prev_exact)
    return e, a_prev, a_now

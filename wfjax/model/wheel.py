"""Two-degree-of-freedom wheel model (Section 3.1, Table 1, Fig. 3 of Pieringer et al. 2014).

The contact force F acts on the small mass m_W (``wheel.small_mass``), joined to half the
wheelset mass M_W by k_W || c_W; M_W hangs from the (fixed) vehicle through the primary
suspension k_S || c_S (Wu & Thompson's simplified wheel; Pieringer 2011). DOFs
q = (q1, q2) = (displacement of m_W, displacement of M_W) [m], positive in the direction of
the applied force (for the wheel: upwards when F is the contact force pushing the wheel up,
so the paper's Eq. 4 reads xi_W = -(g_W * F) + xi_S(P))::

    M = diag(m_W, M_W),
    K = [[k_W, -k_W], [-k_W, k_W + k_S]],   C = [[c_W, -c_W], [-c_W, c_W + c_S]].

The wheel is a finite linear system: :func:`modal_model` gives its 4 state-space poles (two
conjugate pairs, or real poles when overdamped) and residues at the contact point, and
:func:`response` propagates it exactly in discrete time with a first-order hold on the force
(:func:`discrete_step_coefficients`), O(1) per step instead of a convolution.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg

from .._xla import to_device
from ..fields import concrete_positive_numbers
from ..params import Wheel
from .modal import complex_modes, discrete_step_coefficients

__all__ = [
    "WheelModal",
    "system_matrices",
    "receptance",
    "greens_function",
    "static_displacement",
    "modal_model",
    "response",
    "discrete_step_coefficients",
]

_WHEEL_FIELDS = ("wheelset_mass", "suspension_stiffness", "suspension_damping", "small_mass",
                 "contact_stiffness", "contact_damping", "radius", "preload")


def _numbers(wheel: Wheel) -> dict[str, float]:
    if not isinstance(wheel, Wheel):
        raise ValueError(f"wheel must be a wfjax.Wheel, got {type(wheel).__name__}")
    return concrete_positive_numbers(wheel, _WHEEL_FIELDS)


def system_matrices(wheel: Wheel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mass [kg], damping [N s/m] and stiffness [N/m] matrices, each [2, 2] (see module doc)."""
    p = _numbers(wheel)
    kw, ks, cw, cs = (p["contact_stiffness"], p["suspension_stiffness"], p["contact_damping"],
                      p["suspension_damping"])
    m = np.diag([p["small_mass"], p["wheelset_mass"]])
    k = np.array([[kw, -kw], [-kw, kw + ks]])
    c = np.array([[cw, -cw], [-cw, cw + cs]])
    return m, c, k


def receptance(wheel: Wheel, freqs) -> np.ndarray:
    """Point receptance at the contact point (on m_W) [m/N], complex [n_f]; freqs [Hz] >= 0.

    Direct solve of the 2x2 dynamic stiffness K - omega^2 M + i omega C (exp(i omega t)).
    """
    f = np.atleast_1d(np.asarray(freqs, dtype=float))
    if f.ndim != 1 or f.size == 0 or not np.all(np.isfinite(f)) or np.any(f < 0):
        raise ValueError(f"freqs must be a non-empty 1-D array of finite frequencies >= 0 Hz, "
                         f"got {freqs!r}")
    m, c, k = system_matrices(wheel)
    w = 2 * np.pi * f[:, None, None]
    d = k[None] - w**2 * m[None] + 1j * w * c[None]
    rhs = np.broadcast_to(np.array([1.0, 0.0], dtype=complex), (f.size, 2))
    return np.linalg.solve(d, rhs[..., None])[:, 0, 0]


def static_displacement(wheel: Wheel) -> float:
    """Static compression [m] of the wheel model under the preload P: P/k_S + P/k_W.

    This is xi_S(P) of Eq. 4 measured at the contact point (both springs carry P).
    """
    p = _numbers(wheel)
    return p["preload"] / p["suspension_stiffness"] + p["preload"] / p["contact_stiffness"]


class WheelModal(NamedTuple):
    """Poles and contact-point residues of the wheel (a JAX pytree).

    h_W(t) = Re sum_r residues_r exp(poles_r t) for t >= 0 [m/(N s)]: contact-point
    displacement per unit impulse at the contact point. ``residues`` already include the
    factor 2 of conjugate-pair representatives (Im pole > 0); real poles have real residues.

    Fields: poles complex [n] [rad/s]; residues complex [n] [m/(N s)]; n = 2 for the default
    (underdamped) wheel. axle_residues: complex [n] [m/(N s)], the same for the displacement
    of the wheelset mass M_W (the axle box) per unit impulse at the contact: its acceleration
    is -Re sum axle_residues lambda^2 q for the modal states q of the input (the sums of
    axle_residues and of axle_residues lambda vanish: M_W neither moves nor gains speed at the
    instant of an impulse on m_W).
    """

    poles: jax.Array
    residues: jax.Array
    axle_residues: jax.Array | None = None


def modal_model(wheel: Wheel) -> WheelModal:
    """Complex modes of the 2-DOF wheel at the contact point and the axle box
    (:class:`WheelModal`)."""
    m, c, k = system_matrices(wheel)
    w2, phi = scipy.linalg.eigh(k, m)
    poles, weights, a = complex_modes(w2, phi.T @ c @ phi)
    u = phi @ a
    return WheelModal(to_device(poles), to_device(weights * u[0] ** 2),
                      to_device(weights * u[0] * u[1]))


def greens_function(wheel: Wheel, t) -> jax.Array:
    """Impulse response h_W(t) [m/(N s)] at the contact point, times ``t`` [s] (any shape).

    Zero for t < 0. (The paper's g~_W; displacement in the direction of the impulse.)
    """
    model = modal_model(wheel)
    t = jnp.asarray(t, dtype=jnp.result_type(float))
    ts = jnp.maximum(t, 0.0)
    h = jnp.real(jnp.sum(model.residues * jnp.exp(model.poles * ts[..., None]), axis=-1))
    return jnp.where(t >= 0, h, 0.0)


def response(model: WheelModal, force, dt: float) -> jax.Array:
    """Exact contact-point displacement [m] for a force history [N] sampled every ``dt`` [s].

    The force is linear between samples (first-order hold) and starts at rest; the returned
    x_n = int_0^{t_n} h_W(t_n - tau) F(tau) d tau, float [n_t] like ``force`` [n_t]. Each step
    updates the modal states exactly: q_n = e^{lambda dt} q_{n-1} + a_prev F_{n-1} + a_now F_n.
    Pure JAX (``lax.scan``); differentiable in ``force``.
    """
    force = jnp.asarray(force, dtype=jnp.result_type(float))
    decay, a_prev, a_now = discrete_step_coefficients(model.poles, dt)

    def step(carry, f_now):
        q, f_prev = carry
        q = decay * q + a_prev * f_prev + a_now * f_now
        return (q, f_now), jnp.real(jnp.sum(model.residues * q))

    q0 = jnp.zeros_like(model.poles)
    (_, _), x = jax.lax.scan(step, (q0, force[0]), force[1:])
    return jnp.concatenate([jnp.zeros(1, dtype=x.dtype), x])

"""An independent reference for the time loop: the full FE track and its wheels integrated
directly (average-acceleration Newmark, every FE degree of freedom, no modal reduction)."""

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

import wfjax as wf
from wfjax import geometry
from wfjax import interaction as it
from wfjax import track as track_mod
from wfjax import wheel as wheel_mod


def newmark_wheels(flat, speed, x_lead, impact, offsets, dt, n_steps, rail_roughness=None,
                   track=None):
    """Contact forces [n_steps, n] of n wheels (Hertz, profile input; the flat on the first)
    at ``x_lead + offsets`` [m] on the full FE track, average-acceleration Newmark for the
    track and every 2-DOF wheel, Newton on the n forces every step.

    ``rail_roughness``: None or a function r(x) [m] of the rail coordinate (vectorised; positive
    = rail raised), added to every wheel's compression at its contact point. ``track``: the
    :class:`wfjax.Track` (default ``Track()``; per-sleeper supports allowed).
    """
    track, wheel = track or wf.Track(), wf.Wheel()
    fe = track_mod.assemble(track)
    k, m, c = fe.stiffness.tocsc(), fe.mass.tocsc(), fe.damping.tocsc()
    c_h = float(it.prepare("hertz-profile", flat, wheel, track, wf.Material(),
                           wf.SimConfig()).c_h)
    mw, cw, kw = wheel_mod.system_matrices(wheel)
    a0, a1 = 4 / dt**2, 2 / dt
    lu = scipy.sparse.linalg.splu((k + a0 * m + a1 * c).tocsc())
    kw_inv = np.linalg.inv(kw + a0 * mw + a1 * cw)
    p = float(wheel.preload)
    offsets = np.asarray(offsets, dtype=float)
    n_w = offsets.size
    eye = np.eye(n_w)

    def deviation(x):  # profile deviation minus rail roughness at each wheel
        z = np.zeros(n_w)
        z[0] = float(geometry.profile_deviation(flat, x[0] - impact))
        return z if rail_roughness is None else z - rail_roughness(x)

    def loads(x):
        return track_mod._load_vector(fe, x).toarray()

    # static start: the rail under every load, each wheel compressed to carry P
    x = x_lead + offsets
    b = loads(x)
    u = scipy.sparse.linalg.spsolve(k, b @ np.full(n_w, p))
    v, acc = np.zeros_like(u), np.zeros_like(u)
    contact_ref = b.T @ u + (p / c_h) ** (2 / 3) + deviation(x)
    # wheel i around its static state: M q'' + C q' + K q = e1 (P - F_i), q1 downwards
    q, qv, qa = np.zeros((n_w, 2)), np.zeros((n_w, 2)), np.zeros((n_w, 2))
    forces = np.full((n_steps, n_w), p)
    w_c = kw_inv[0, 0]
    for n in range(1, n_steps):
        x = x_lead + speed * dt * n + offsets
        b = loads(x)
        u_free = lu.solve(m @ (a0 * u + 4 / dt * v + acc) + c @ (a1 * u + v))
        g = lu.solve(b)
        rail_free, rail_c = b.T @ u_free, b.T @ g
        rhs_w = (mw @ (a0 * q + 4 / dt * qv + qa).T + cw @ (a1 * q + qv).T).T  # [n_w, 2]
        w_free = (kw_inv @ (rhs_w + np.array([p, 0.0])).T)[0]
        z = deviation(x)
        compliance = w_c * eye + rail_c
        f = forces[n - 1].copy()
        for _ in range(60):
            comp = contact_ref + w_free - rail_free - compliance @ f - z
            fh = c_h * np.maximum(comp, 0.0) ** 1.5
            dfh = 1.5 * c_h * np.sqrt(np.maximum(comp, 0.0))
            step = np.linalg.solve(eye + dfh[:, None] * compliance, f - fh)
            f = np.maximum(f - step, 0.0)
            if np.max(np.abs(step)) < 1e-7:
                break
        forces[n] = f
        u_new = u_free + g @ f
        acc_new = a0 * (u_new - u) - 4 / dt * v - acc
        v, u, acc = v + 0.5 * dt * (acc + acc_new), u_new, acc_new
        q_new = (kw_inv @ (rhs_w + np.stack([p - f, np.zeros(n_w)], axis=1)).T).T
        qa_new = a0 * (q_new - q) - 4 / dt * qv - qa
        qv, q, qa = qv + 0.5 * dt * (qa + qa_new), q_new, qa_new
    return forces

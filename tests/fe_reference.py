"""An independent reference for the time loop: the full FE track and its wheels integrated
directly (average-acceleration Newmark, every FE degree of freedom, no modal reduction)."""

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

import wfjax as wf
from wfjax.contact.laws import prepare
from wfjax.model import beam as beam_mod
from wfjax.model import ends, geometry, sleepers, supports
from wfjax.model import fe as fe_mod
from wfjax.model import track as track_mod
from wfjax.model import wheel as wheel_mod


def newmark_wheels(flat, speed, x_lead, impact, offsets, dt, n_steps, rail_roughness=None,
                   track=None, supports_out=None):
    """Contact forces [n_steps, n] of n wheels (Hertz, profile input; the flat on the first)
    at ``x_lead + offsets`` [m] on the full FE track, average-acceleration Newmark for the
    track and every 2-DOF wheel, Newton on the n forces every step.

    ``rail_roughness``: None or a function r(x) [m] of the rail coordinate (vectorised; positive
    = rail raised), added to every wheel's compression at its contact point. ``track``: the
    :class:`wfjax.Track` (default ``Track(n_bays=24)``; per-sleeper supports allowed). Hanging
    sleepers (``ballast_gap > 0``) are one-sided Kelvin-Voigt supports on their DOFs,
    F = k_B e + c_B e' while e = u - gap > 0 and that is >= 0 (e' the Newmark velocity),
    solved with the wheels by Newton every step; ``supports_out``: a list that receives
    their forces [n_steps, n_s]. A load inside an element adds its deflection there that
    the shape functions miss (static, :func:`wfjax.model.fe.element_interior_compliance`),
    so the reference is exact Timoshenko statics under the moving loads.
    """
    track, wheel = ends.resolved(track or wf.Track(n_bays=24)), wf.Wheel()
    fe = fe_mod.assemble(track)
    k, m, c = fe.stiffness.tocsc(), fe.mass.tocsc(), fe.damping.tocsc()
    c_h = float(prepare("hertz-profile", flat, wheel, track, wf.Material(),
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
        return fe_mod.load_vector(fe, x).toarray()

    def own(x):  # each load's deflection inside its element (exact Timoshenko statics)
        return beam_mod.element_interior_compliance(track, track_mod.element_fraction(fe, x))

    hang = supports.hanging_sleepers(track)
    arrays = sleepers.support_arrays(track)
    gap, k_s, c_s = (arrays[n][hang] for n in ("ballast_gap", "ballast_stiffness",
                                                "ballast_damping"))
    c_s = c_s * fe_mod.end_grading(arrays["ballast_damping"].size,
                                   int(track.absorbing_sleepers))[hang]
    e_s = np.zeros((k.shape[0], hang.size))
    e_s[fe.n_rail_dof + hang, np.arange(hang.size)] = 1.0
    g_s = lu.solve(e_s) if hang.size else e_s  # dynamic: unit upward loads at the sleepers

    # static start: the rail under every load, each wheel compressed to carry P, the hanging
    # sleepers' ballast by Newton on its piecewise-linear law
    x = x_lead + offsets
    b = loads(x)
    k_lu = scipy.sparse.linalg.splu(k)
    u_p = k_lu.solve(b @ np.full(n_w, p))
    f_s = np.zeros(hang.size)
    if hang.size:
        s_static = e_s.T @ k_lu.solve(e_s)
        for _ in range(50):
            closure = e_s.T @ u_p - s_static @ f_s - gap
            active = closure > 0
            f_new = np.linalg.solve(np.eye(hang.size) + (k_s * active)[:, None] * s_static,
                                    k_s * active * (e_s.T @ u_p - gap))
            if np.allclose(f_new, f_s, rtol=1e-14, atol=1e-9):
                break
            f_s = f_new
    u = u_p - k_lu.solve(e_s @ f_s) if hang.size else u_p
    v, acc = np.zeros_like(u), np.zeros_like(u)
    support_forces = np.zeros((n_steps, hang.size))
    support_forces[0] = f_s
    contact_ref = b.T @ u + own(x) * p + (p / c_h) ** (2 / 3) + deviation(x)
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
        compliance = w_c * eye + rail_c + np.diag(own(x))
        # all unknowns [wheel forces, support forces]: approach/closure = c0 - A y
        a_ws = b.T @ g_s
        a_mat = np.block([[compliance, -a_ws], [-e_s.T @ g, e_s.T @ g_s]])
        c0 = np.concatenate([contact_ref + w_free - rail_free - z, e_s.T @ u_free - gap])
        v_s_old, u_s_old = e_s.T @ v, e_s.T @ u
        y = np.concatenate([forces[n - 1], support_forces[n - 1]])
        ey = np.eye(y.size)
        for _ in range(60):
            comp = c0 - a_mat @ y
            fh = c_h * np.maximum(comp[:n_w], 0.0) ** 1.5
            dfh = 1.5 * c_h * np.sqrt(np.maximum(comp[:n_w], 0.0))
            e = comp[n_w:]
            kv = k_s * e + c_s * (2 * (e + gap - u_s_old) / dt - v_s_old)
            on = (e > 0) & (kv > 0)
            fs_law, dfs = np.where(on, kv, 0.0), np.where(on, k_s + 2 * c_s / dt, 0.0)
            dlaw = np.concatenate([dfh, dfs])
            step = np.linalg.solve(ey + dlaw[:, None] * a_mat, y - np.concatenate([fh, fs_law]))
            y = np.maximum(y - step, 0.0)
            if np.max(np.abs(step)) < 1e-7:
                break
        f, f_s = y[:n_w], y[n_w:]
        forces[n], support_forces[n] = f, f_s
        u_new = u_free + g @ f - g_s @ f_s
        acc_new = a0 * (u_new - u) - 4 / dt * v - acc
        v, u, acc = v + 0.5 * dt * (acc + acc_new), u_new, acc_new
        q_new = (kw_inv @ (rhs_w + np.stack([p - f, np.zeros(n_w)], axis=1)).T).T
        qa_new = a0 * (q_new - q) - 4 / dt * qv - qa
        qv, q, qa = qv + 0.5 * dt * (qa + qa_new), q_new, qa_new
    if supports_out is not None:
        supports_out.append(support_forces)
    return forces

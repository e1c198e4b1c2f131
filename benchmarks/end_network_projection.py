"""End networks by projection (model-order reduction) instead of an L-BFGS fit: how close, how
small and how fast (``wfjax.model.ends``; docs/convergence.md, "A fitted passive end network").

1. A *buffer*: ``--bays`` bays of the track itself (the rail's Timoshenko elements, pads,
   sleepers and ballast of :func:`wfjax.model.periodic._cell_matrices`), clamped at its far
   end, with an absorbing layer over its last ``--layer`` fraction: extra rail damping
   ``s^2 (alpha M_e + beta K_e)`` per element, s rising 0 -> 1 through the layer. Its exact
   boundary stiffness at the near end node (banded solves per frequency, Schur complement onto
   w, theta) is measured against the semi-infinite track's K_R (:func:`ends.boundary_stiffness`)
   with the measure of :func:`ends.fit_error`: the largest relative Frobenius error (theta
   scaled by ``ends.THETA_SCALE``) on 10-2500 Hz leaving out +-``ends.EDGE_EXCLUDED`` Hz around
   the band edge; and on 2.5-20 kHz (the fit's HF term's grid), largest and median.
2. Its interior reduced to ``n_aux`` DOFs by a one-sided congruence T = blockdiag(I_2, V)
   (K_r = T^T K T, likewise C, M: symmetric positive semi-definite, so passive by
   construction), V real orthonormal: Re and Im of the interior's responses
   X(w_k) = -S_ii(w_k)^-1 S_ib(w_k) to the two boundary DOFs at frequencies w_k (complex
   symmetric Galerkin: K_r matches the buffer's value and derivative there), the frequencies
   chosen greedily (each adds the frequency of the largest error against the buffer's own
   exact stiffness on a candidate grid; K_R is not needed to build it), ``n_aux / 4`` of
   them; and, for comparison, POD (the ``n_aux`` leading left singular vectors of many
   frequencies' responses).
3. The reduced network's error against K_R (the fit_error measure; one row also through
   ``ends.fit_error`` on its Cholesky factors in ``ends.matrices``' format), its HF error, its
   K_r, C_r, M_r's least eigenvalues (relative to their largest) and the seconds to build it
   (buffer, responses, greedy choice, projection; the band edge and K_R not included).

Tracks: the default (``Track.comparison(ends="network")``), those of
``benchmarks/end_network.py --sections warm`` (pads 60 and 240 MN/m, ballast 70 MN/m,
sleepers 0.6 m apart) and the default on 8 and 16 elements per bay.

Run: ``python benchmarks/end_network_projection.py [--tracks default,pads60,...]
[--n-aux 24,48,96] [--methods greedy,pod] [--bays 200] [--layer 0.34] [--alpha 1000]
[--beta 1e-5] [--check-ends]`` (0.5-3 minutes a track on 2 cores with other jobs, most of it
the band edge; n_aux above about 128 takes longer); writes
``benchmarks/results/end_network_projection.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import time

import numpy as np
import scipy.linalg
import scipy.sparse

import wfjax as wf
from wfjax.model import ends
from wfjax.model import periodic as P
from wfjax.model.beam import element_matrices

TRACKS = {"default": {},
          "pads60": {"pad_stiffness": 60e6},
          "pads240": {"pad_stiffness": 240e6},
          "ballast70": {"ballast_stiffness": 70e6},
          "sleepers0.6": {"sleeper_spacing": 0.6},
          "ne8": {"elements_per_bay": 8},
          "ne16": {"elements_per_bay": 16}}
BAND = 4  # the buffer's half bandwidth in its node-by-node DOF order


def make_track(name: str) -> wf.Track:
    return wf.Track.comparison(ends="network", **TRACKS[name])


# ---------------------------------------------------------------------------------------------
# The buffer: bays of the track in a banded DOF order, an absorbing layer at its far end


class Buffer:
    """``n_bays`` bays of ``track`` from a sleeper's node (its sleeper included, as K_R's),
    clamped at the far node; DOFs node by node (w, theta, then the node's sleeper if any), so
    K, C, M are banded (half bandwidth :data:`BAND`). DOFs 0, 1: the near end node's w, theta."""

    def __init__(self, track: wf.Track, n_bays: int, layer: float, alpha: float, beta: float):
        p, ne = P._numbers(track), int(track.elements_per_bay)
        le = float(p["sleeper_spacing"]) / ne
        ke, me, _ = element_matrices(p["bending_stiffness"], p["shear_stiffness"],
                                     p["rail_mass"], p["rail_rotary_inertia"], le)
        n_el = n_bays * ne
        index, n = [], 0  # each rail node's (w, theta) DOFs; sleepers after their node
        sleeper = {}
        for j in range(n_el):  # the far node (n_el) is clamped: no DOFs
            index.append((n, n + 1))
            n += 2
            if j % ne == 0:
                sleeper[j] = n
                n += 1
        rows, cols, vk, vc, vm = [], [], [], [], []

        def add(dofs, k, c, m):
            for a, da in enumerate(dofs):
                if da is None:
                    continue
                for b, db in enumerate(dofs):
                    if db is None:
                        continue
                    rows.append(da)
                    cols.append(db)
                    vk.append(k[a, b])
                    vc.append(c[a, b])
                    vm.append(m[a, b])

        start = (1.0 - layer) * n_el
        for e in range(n_el):
            s = max(0.0, (e + 0.5 - start) / (n_el - start)) if layer > 0 else 0.0
            dofs = list(index[e]) + (list(index[e + 1]) if e + 1 < n_el else [None, None])
            add(dofs, ke, s * s * (alpha * me + beta * ke), me)
        kp, cp = float(p["pad_stiffness"]), float(p["pad_damping"])
        bonded = float(p["ballast_gap"]) == 0
        kb, cb = (float(p["ballast_stiffness"]), float(p["ballast_damping"])) if bonded else (0, 0)
        ms = float(p["sleeper_mass"])
        for j, sl in sleeper.items():
            w = index[j][0]
            add([w, sl], np.array([[kp, -kp], [-kp, kp + kb]]),
                np.array([[cp, -cp], [-cp, cp + cb]]), np.diag([0.0, ms]))
        shape = (n, n)
        self.k, self.c, self.m = (scipy.sparse.csr_matrix((v, (rows, cols)), shape=shape)
                                  for v in (vk, vc, vm))
        self.n = n
        self.bands = tuple(_banded(a) for a in (self.k, self.c, self.m))

    def dynamic(self, w: float):
        """(S_bb [2, 2], S_ib [n - 2, 2] dense, S_ii banded) at ``w`` [rad/s]."""
        kb, cb, mb = self.bands
        ab = kb + 1j * w * cb - w * w * mb
        s = (self.k + 1j * w * self.c - w * w * self.m)[:, :2].toarray()
        return s[:2], s[2:], ab[:, 2:]

    def response(self, w: float):
        """(the exact boundary stiffness [2, 2], X = -S_ii^-1 S_ib [n - 2, 2]) at ``w``."""
        s_bb, s_ib, ab = self.dynamic(w)
        x = -scipy.linalg.solve_banded((BAND, BAND), ab, s_ib, check_finite=False)
        return s_bb + s_ib.T @ x, x

    def stiffness(self, f) -> np.ndarray:
        """[n_f, 2, 2] the buffer's exact boundary stiffness at ``f`` [Hz]."""
        return np.array([self.response(2 * math.pi * fi)[0] for fi in np.atleast_1d(f)])


def _banded(a) -> np.ndarray:
    a = scipy.sparse.dia_matrix(a)
    n = a.shape[0]
    ab = np.zeros((2 * BAND + 1, n))
    for off, data in zip(a.offsets, a.data, strict=True):
        if abs(off) > BAND:
            raise ValueError("bandwidth")
        ab[BAND - off] += data  # dia data[j] is column j's entry on diagonal off
    return ab


# ---------------------------------------------------------------------------------------------
# Errors with the measure of ends.fit_error


T_SCALE = np.diag([1.0, 1.0 / ends.THETA_SCALE])


def rel_err(k: np.ndarray, target: np.ndarray) -> np.ndarray:
    """[n_f] relative Frobenius errors, theta scaled (ends._relative_error)."""
    a = np.einsum("ij,fjk,kl->fil", T_SCALE, k - target, T_SCALE)
    b = np.einsum("ij,fjk,kl->fil", T_SCALE, target, T_SCALE)
    return np.linalg.norm(a, axis=(1, 2)) / np.linalg.norm(b, axis=(1, 2))


def grids(edge: float) -> tuple[np.ndarray, np.ndarray]:
    """(fit_error's frequencies beside the band edge, the fit's 2.5-20 kHz grid) [Hz]."""
    f = np.geomspace(10, 2500, 600)
    f = np.unique(np.concatenate([f, edge + np.arange(-100, 100.01, 0.25)]))
    return f[np.abs(f - edge) > ends.EDGE_EXCLUDED], np.geomspace(2500, 20000, 300)[1:]


def net_stiffness(mats, f) -> np.ndarray:
    return ends.network_stiffness(mats, 2 * np.pi * np.asarray(f))


def summary(k_band, k_hf, target_band, target_hf, f_band) -> dict:
    e, h = rel_err(k_band, target_band), rel_err(k_hf, target_hf)
    return {"beside_edge_max_pct": round(100 * float(e.max()), 3),
            "at_Hz": round(float(f_band[np.argmax(e)]), 2),
            "median_pct": round(100 * float(np.median(e)), 3),
            "hf_max_pct": round(100 * float(h.max()), 2),
            "hf_median_pct": round(100 * float(np.median(h)), 3)}


# ---------------------------------------------------------------------------------------------
# The projection


def project(buf: Buffer, basis: np.ndarray):
    """(K_r, C_r, M_r) [2 + n_aux]^2 by the congruence T = blockdiag(I_2, basis)."""
    out = []
    for a in (buf.k, buf.c, buf.m):
        a = a.tocsr()
        abb = a[:2, :2].toarray()
        abi = a[:2, 2:] @ basis
        aii = basis.T @ (a[2:, 2:] @ basis)
        r = np.block([[abb, abi], [abi.T, aii]])
        out.append(0.5 * (r + r.T))
    return tuple(out)


def orthonormal(cols: np.ndarray, n_max: int, rtol: float = 1e-10) -> np.ndarray:
    """Up to ``n_max`` orthonormal columns spanning ``cols`` (SVD, near-dependent dropped)."""
    u, s, _ = np.linalg.svd(cols, full_matrices=False)
    keep = min(n_max, int(np.sum(s > rtol * s[0])))
    return u[:, :keep]


def _columns(x: np.ndarray) -> np.ndarray:
    x = x / np.linalg.norm(x, axis=0)  # each boundary DOF's response, unit norm
    return np.concatenate([x.real, x.imag], axis=1)


def extend(v: np.ndarray, cols: np.ndarray, n_max: int, rtol: float = 1e-8) -> np.ndarray:
    """``v`` with ``cols`` appended, orthonormalised (Gram-Schmidt twice, then an SVD of the
    remainder; near-dependent directions dropped), at most ``n_max`` columns."""
    for _ in range(2):
        cols = cols - v @ (v.T @ cols)
    u, s, _ = np.linalg.svd(cols, full_matrices=False)
    keep = min(n_max - v.shape[1], int(np.sum(s > rtol)))
    return np.concatenate([v, u[:, :keep]], axis=1)


def greedy(buf: Buffer, n_aux: int, edge: float, first=(10.0,), candidates=None,
           hf_weight: float = ends.HF_WEIGHT):
    """V [n - 2, n_aux] from the buffer's responses at greedily chosen frequencies: start at
    ``first``; each step adds the candidate frequency where the reduced network is farthest
    from the buffer's exact stiffness (above 2.5 kHz weighted ``hf_weight``, as the fit's HF
    term), its 4 columns (Re, Im of the 2 boundary DOFs' responses) orthonormalised onto V.
    Returns (V, the frequencies [Hz])."""
    if candidates is None:
        candidates = np.unique(np.concatenate([
            np.geomspace(10, 2500, 160), edge + np.array([-60, -30, -15, -8, -6, 6, 8, 15, 30]),
            np.geomspace(2600, 20000, 25)]))
    exact, xs = [], []
    for fi in candidates:
        k, x = buf.response(2 * math.pi * fi)
        exact.append(k)
        xs.append(_columns(x))
    target, weight = np.array(exact), np.where(candidates > 2500, hf_weight, 1.0)
    v, chosen = np.zeros((buf.n - 2, 0)), []
    for fi in first:
        v = extend(v, _columns(buf.response(2 * math.pi * fi)[1]), n_aux)
        chosen.append(float(fi))
    left = np.ones(candidates.size, bool)
    while v.shape[1] < n_aux and left.any():
        e = weight * rel_err(net_stiffness(project(buf, v), candidates), target)
        i = int(np.argmax(np.where(left, e, -1.0)))
        left[i] = False
        v = extend(v, xs[i], n_aux)
        chosen.append(float(candidates[i]))
    return v, chosen


def pod(buf: Buffer, n_aux: int, edge: float) -> np.ndarray:
    """V: the ``n_aux`` leading left singular vectors of the responses at many frequencies."""
    f = np.unique(np.concatenate([np.geomspace(10, 2500, 60), edge + np.linspace(-40, 40, 17),
                                  np.geomspace(2600, 20000, 15)]))
    cols = np.concatenate([_columns(buf.response(2 * math.pi * fi)[1]) for fi in f], axis=1)
    return orthonormal(cols, n_aux)


def to_factors(mats, jitter: float = 1e-12) -> np.ndarray:
    """``ends.matrices``' stacked lower-triangular factors of (K, C, M), a relative
    ``jitter`` on the diagonal for Cholesky."""
    n = mats[0].shape[0]
    tri = np.tril_indices(n)
    out = []
    for a, s in zip(mats, ends.SCALES, strict=True):
        a = a / s
        lower = np.linalg.cholesky(a + jitter * np.trace(a) / n * np.eye(n))
        out.append(lower[tri])
    return np.concatenate(out)


def sanity(mats) -> dict:
    """Least eigenvalue of each of K_r, C_r, M_r over its largest; the interior's highest
    undamped natural frequency [Hz] (boundary clamped)."""
    out = {}
    for name, a in zip(("K", "C", "M"), mats, strict=True):
        lam = np.linalg.eigvalsh(a)
        out[f"min_eig_rel_{name}"] = float(lam[0] / lam[-1])
    lam = scipy.linalg.eigh(mats[0][2:, 2:], mats[2][2:, 2:], eigvals_only=True)
    out["highest_internal_Hz"] = round(float(np.sqrt(max(lam[-1], 0)) / (2 * np.pi)), 1)
    return out


# ---------------------------------------------------------------------------------------------


def run_track(name: str, a) -> dict:
    track = make_track(name)
    t0 = time.perf_counter()
    edge = ends.band_edge(track)
    f_band, f_hf = grids(edge)
    t_edge = time.perf_counter() - t0
    t0 = time.perf_counter()
    target_band = ends.boundary_stiffness(track, f_band)
    target_hf = ends.boundary_stiffness(track, f_hf)
    row = {"elements_per_bay": int(track.elements_per_bay), "band_edge_Hz": round(edge, 2),
           "band_edge_s": round(t_edge, 1), "k_r_s": round(time.perf_counter() - t0, 1)}
    print(name, row, flush=True)
    t0 = time.perf_counter()
    buf = Buffer(track, a.bays, a.layer, a.alpha, a.beta)
    t_buf = time.perf_counter() - t0
    row["buffer"] = {"bays": a.bays, "layer": a.layer, "alpha": a.alpha, "beta": a.beta,
                     "dofs": buf.n, "build_s": round(t_buf, 2),
                     **summary(buf.stiffness(f_band), buf.stiffness(f_hf), target_band,
                               target_hf, f_band)}
    print(" buffer", row["buffer"], flush=True)
    row["reduced"] = []
    for n_aux in a.n_aux:
        for method in a.methods:
            t0 = time.perf_counter()
            if method == "greedy":
                v, chosen = greedy(buf, n_aux, edge)
            else:
                v, chosen = pod(buf, n_aux, edge), None
            mats = project(buf, v)
            secs = time.perf_counter() - t0 + t_buf
            r = {"method": method, "n_aux": int(v.shape[1]), "construct_s": round(secs, 2),
                 **summary(net_stiffness(mats, f_band), net_stiffness(mats, f_hf),
                           target_band, target_hf, f_band), **sanity(mats)}
            if chosen is not None:
                r["frequencies_Hz"] = [round(x, 1) for x in chosen]
            if a.check_ends and v.shape[1] == ends.N_AUX:
                try:
                    r["ends_fit_error_pct"] = round(100 * ends.fit_error(track,
                                                                         to_factors(mats)), 3)
                except np.linalg.LinAlgError as exc:
                    r["ends_fit_error_pct"] = f"Cholesky failed: {exc}"
            print(" ", r, flush=True)
            row["reduced"].append(r)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tracks", default=",".join(TRACKS))
    ap.add_argument("--n-aux", default="24,48,96")
    ap.add_argument("--methods", default="greedy")
    ap.add_argument("--bays", type=int, default=200)
    ap.add_argument("--layer", type=float, default=0.34)
    ap.add_argument("--alpha", type=float, default=1000.0)
    ap.add_argument("--beta", type=float, default=1e-5)
    ap.add_argument("--check-ends", action="store_true",
                    help="also ends.fit_error on the Cholesky factors (n_aux = ends.N_AUX)")
    ap.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results"
                                         / "end_network_projection.json"))
    a = ap.parse_args()
    a.n_aux = [int(x) for x in a.n_aux.split(",")]
    a.methods = a.methods.split(",")
    out = pathlib.Path(a.out)
    result = json.loads(out.read_text()) if out.exists() else {}
    for name in a.tracks.split(","):
        key = name if a.methods == ["greedy"] else f"{name}, {'+'.join(a.methods)}"
        result[key] = run_track(name, a)
        out.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()

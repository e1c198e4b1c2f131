"""Parametric 3D contact law (wfjax.contact.family): cold build time and pointwise accuracy.

Builds, from an empty (temporary) cache, the family of the paper's Fig. 8 set (rounded flats,
l = 1.76 l0, depths 0.25-2.00 mm) and a new-flat family over the same depths (R_W = R_R =
0.45 m, 1 mm elements), then compares each family with the exact per-flat table
(``tables.build_table_3d``) at the 8 Fig. 8 depths (all between the lattice's depth nodes
0.1375, 0.275, 0.55, 1.1, 2.2 mm; lambda = 1.76 between 1.66 and 1.86): relative force error
over a grid of (delta, s) with 20 kN < F < 600 kN (also by force band and as
|dF| / max(F, 50 kN)), and the onset error.

Run: ``python benchmarks/bench_family.py [--kinds rounded,new] [--element 1e-3]
[--s-map edges|scaled] [--min-length-nodes 3]`` (default: each kind's default s-map, and
two length-factor nodes, 1.66 and 1.86, for lambda = 1.76).
"""

from __future__ import annotations

import argparse
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

import wfjax as wf  # noqa: E402
from wfjax.contact import family, family_build, family_spec, interpolation, tables  # noqa: E402

DEPTHS = np.arange(1, 9) * 0.25e-3
LAMBDA = 1.76
BANDS = ((20e3, 50e3), (50e3, 100e3), (100e3, 300e3), (300e3, 600e3))


def flat_of(kind, d):
    return wf.Flat.rounded_relative(d, LAMBDA) if kind == "rounded" else wf.Flat.new(d)


def accuracy(fam, kind, d, h, n_s=801, n_t=60):
    flat = flat_of(kind, d)
    t0 = time.perf_counter()
    tab = jax.block_until_ready(tables.build_table_3d(flat, element_size=h))
    t_exact = time.perf_counter() - t0
    s = np.linspace(float(tab.s_min), -float(tab.s_min), n_s)
    on_t = np.asarray(jax.vmap(lambda x: interpolation.table_onset(tab, x))(s))
    on_f = np.asarray(jax.jit(jax.vmap(family.family_column, (None, 0, None, None)))(
        fam, jnp.asarray(s), d, flat.length).onset)
    S, T = np.meshgrid(s, np.linspace(0.02, 1.0, n_t), indexing="ij")
    D = on_t[:, None] + float(tab.c_max) * T**2
    f_t = np.asarray(jax.jit(jax.vmap(interpolation.table_force, (None, 0, 0)))(
        tab, jnp.asarray(D.ravel()), jnp.asarray(S.ravel())))
    f_f = np.asarray(jax.jit(jax.vmap(family.family_force, (None, 0, 0, None, None)))(
        fam, jnp.asarray(D.ravel()), jnp.asarray(S.ravel()), d, flat.length))
    band = (f_t > 20e3) & (f_t < 600e3)
    rel = np.abs(f_f - f_t) / np.where(band, f_t, 1.0)
    node = bool(np.any(np.isclose(fam.spec.depths, d, rtol=1e-9)))
    row = {"depth_mm": d * 1e3, "node": node, "max_rel_%": rel[band].max() * 100,
           "p99_rel_%": np.percentile(rel[band], 99) * 100,
           "max_dF/max(F,50kN)_%": (np.abs(f_f - f_t) / np.maximum(f_t, 50e3))[
               f_t < 600e3].max() * 100,
           "onset_um": np.abs(on_f - on_t).max() * 1e6, "exact_build_s": t_exact}
    for lo, hi in BANDS:
        m = (f_t > lo) & (f_t < hi)
        row[f"{lo / 1e3:.0f}-{hi / 1e3:.0f}kN_%"] = rel[m].max() * 100 if m.any() else np.nan
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kinds", default="rounded,new")
    ap.add_argument("--element", type=float, default=1e-3)
    ap.add_argument("--no-accuracy", action="store_true")
    ap.add_argument("--s-map", default=None, choices=family_spec.S_MAPS)
    ap.add_argument("--min-length-nodes", type=int, default=2)
    args = ap.parse_args()
    h = args.element
    for kind in args.kinds.split(","):
        lam = [LAMBDA] if kind == "rounded" else None
        spec = family_spec.family_spec(kind, DEPTHS, lam, element_size=h, s_map=args.s_map,
                                  min_length_nodes=args.min_length_nodes)
        with tempfile.TemporaryDirectory() as cache:
            t0 = time.perf_counter()
            fam = family_build.build_family(spec, cache_dir=cache, progress=True)
            t_cold = time.perf_counter() - t0
            t0 = time.perf_counter()
            family_build.build_family(spec, cache_dir=cache)
            t_warm = time.perf_counter() - t0
        print(f"\n{kind}: nodes {np.round(spec.depths * 1e3, 4).tolist()} mm"
              + (f", l/l0 {spec.length_factors.tolist()}" if kind == "rounded" else "")
              + f"; s_map {spec.s_map}; cold build {t_cold:.1f} s, cached load {t_warm:.2f} s, "
              f"converged {float(fam.converged) == 1.0}", flush=True)
        # evaluation cost: 10^4 points, jit + vmap (two-stage form)
        ev = jax.jit(jax.vmap(family.family_force, (None, 0, 0, None, None)))
        pts = jnp.linspace(-0.05, 0.05, 10_000)
        dd = jnp.full_like(pts, 0.2e-3)
        length = flat_of(kind, 0.9e-3).length
        ev(fam, dd, pts, 0.9e-3, length).block_until_ready()
        t0 = time.perf_counter()
        ev(fam, dd, pts, 0.9e-3, length).block_until_ready()
        print(f"evaluation: {(time.perf_counter() - t0) / 1e4 * 1e6:.2f} us per force "
              "(10^4-point vmap, after compile)")
        if args.no_accuracy:
            continue
        rows = [accuracy(fam, kind, d, h) for d in DEPTHS]
        keys = list(rows[0])
        print(" | ".join(keys))
        for r in rows:
            print(" | ".join(f"{r[k]:.3f}" if isinstance(r[k], float) else str(r[k])
                             for k in keys), flush=True)
        between = [r for r in rows if not r["node"]]
        on_node = [r["max_rel_%"] for r in rows if r["node"]]
        bands = "; ".join(f"{k[:-2]} {max(r[k] for r in between):.2f} %" for k in keys
                          if k.endswith("kN_%"))
        print(f"{kind}: between nodes max rel (20-600 kN) "
              f"{max(r['max_rel_%'] for r in between):.3f} % (by band: {bands}), at nodes "
              f"{max(on_node) if on_node else float('nan'):.3f} %; max onset error "
              f"{max(r['onset_um'] for r in rows):.4f} um; exact tables "
              f"{sum(r['exact_build_s'] for r in rows):.0f} s in all")


if __name__ == "__main__":
    main()

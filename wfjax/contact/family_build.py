"""Building a :class:`~wfjax.contact.family.FlatFamily`: the node tables of its lattice nodes,
solved together (windowed Kalker solves shared across nodes, the cores in parallel) and cached
one file per node, so families that share nodes share their solves."""

from __future__ import annotations

import sys
import time

import jax.numpy as jnp
import numpy as np

from .._parallel import core_pool, map_per_core
from .._xla import to_device
from ..params import Material
from . import influence, interpolation, kalker, table_spec, tables, windows
from .family import FlatFamily
from .family_spec import FamilySpec, lattice_depth, lattice_length_factor, node_flat

_DEFAULT_MATERIAL = Material()

# Part of every node's cache key: raise it when the node builder's results change, so a cache
# written by an older builder of the same wfjax version is never served (2: issue 20's
# faster CG, forces within 1e-9 of revision 1's; 3: a new flat's columns crowd at its centre,
# FamilySpec.stretch).
NODE_BUILDER_REVISION = 3


FAMILY_WINDOW_SIZES = 6  # window sizes of a family build (one compiled solver each, shared)


def _node_geometry(spec: FamilySpec, idx: int):
    """(depth [m], l / l0, flat, s [n_cols] m) of node ``idx``: columns s_j = j step h >= 0
    (mirrored by build_family)."""
    n_l = len(spec.length_index)
    k, j = spec.depth_index[idx // n_l], spec.length_index[idx % n_l]
    depth, lam = lattice_depth(k), lattice_length_factor(j)
    flat = node_flat(spec.kind, depth, lam, spec.wheel_radius)
    s = interpolation.column_positions(
        np.arange(spec.node_columns[idx]) * spec.node_steps[idx] * spec.element_size,
        spec.stretch)
    return depth, lam, flat, s


def _node_key(spec: FamilySpec, idx: int, material: Material, tol: float) -> dict:
    depth, lam, _, _ = _node_geometry(spec, idx)
    nx, ny = spec.grids[idx]
    return {"kind": spec.kind, "depth": depth,
            "length_factor": lam if spec.kind == "rounded" else None,
            "wheel_radius": spec.wheel_radius, "rail_head_radius": spec.rail_head_radius,
            "element_size": spec.element_size, "c_max": spec.c_max, "n_t": spec.n_t,
            "step": spec.node_steps[idx], "n_cols": spec.node_columns[idx], "nx": nx, "ny": ny,
            "stretch": spec.stretch,
            "youngs_modulus": float(material.youngs_modulus),
            "poisson_ratio": float(material.poisson_ratio), "tol": tol,
            "builder_revision": NODE_BUILDER_REVISION}


class _SharedBuilder:
    """The window sizes and solvers shared by every node of a family that is built.

    The nodes share a grid (the largest node grid: it holds every node's overlaps, and with
    windows its size costs nothing) and one set of window sizes (merged over all their
    solves); each size's solver (:func:`wfjax.contact.windows.window_solver`) compiles once,
    in parallel on the process's core pool, and serves every node (and every table of the
    process with that window).
    """

    def __init__(self, spec: FamilySpec, indices, material: Material, tol: float):
        self.geometry = {i: _node_geometry(spec, i) for i in indices}
        self.n = max(len(g[3]) for g in self.geometry.values())
        self.tspec = table_spec.TableSpec(
            nx=max(spec.grids[i][0] for i in indices), ny=max(spec.grids[i][1] for i in indices),
            element_size=spec.element_size, s_max=float(interpolation.column_positions(
                (self.n - 1) * spec.element_size, spec.stretch)),
            n_s=self.n, c_max=spec.c_max, n_t=spec.n_t, symmetric=True,
            wheel_radius=spec.wheel_radius, rail_head_radius=spec.rail_head_radius,
            stretch=spec.stretch)
        self.gaps, boxes, self.shared = {}, {}, {}
        cs = table_spec.compression_nodes(self.tspec)
        for i, (_, _, flat, s) in self.geometry.items():
            gaps, onsets = windows.column_gaps(self.tspec, flat, s)
            self.gaps[i] = gaps, onsets
            self.shared[i] = tables.shared_prefix(gaps, onsets, cs)
            rel = gaps - gaps.min(axis=(1, 2), keepdims=True)
            boxes[i] = windows.boxes_from_gaps(self.tspec, rel, windows.WINDOW_MARGIN)
        solved = [tables.solved_mask(self.shared[i], len(cs)) for i in boxes]
        self.sizes = tuple(windows.merge_sizes(windows.needed_sizes(list(boxes.values()), solved),
                                               FAMILY_WINDOW_SIZES,
                                               windows.COST_PER_WINDOW_SIZE))
        self.plans = {i: windows.assign_windows(self.tspec, b, self.sizes)
                      for i, b in boxes.items()}
        dtype = next(iter(self.gaps.values()))[0].dtype
        self.material = windows.solver_inputs(material, dtype)
        self.estar = float(influence.combined_modulus(material))
        pool = core_pool()
        self.solvers = [pool.submit(windows.window_solver, size, spec.element_size, tol, dtype)
                        for size in self.sizes]

    def __call__(self, idx: int):
        gaps, onsets = self.gaps[idx]
        plan, shared = self.plans[idx], self.shared[idx]
        solvers = [c.result() for c in self.solvers]
        cs = table_spec.compression_nodes(self.tspec)

        def column(i, reference=None, keep=False):
            return tables._solve_column(solvers, self.sizes, gaps[i], onsets[i], cs,
                                        plan.size_index[i], plan.x0[i], plan.y0[i],
                                        self.material, self.estar, int(shared[i]), reference,
                                        keep)

        last = len(onsets) - 1  # the smooth wheel: solved first, the others share its solves
        reference = column(last, keep=bool(np.any(shared)))
        solved = [column(i, reference) for i in range(last)] + [reference]
        force, slope = table_spec.column_outputs(self.tspec, np.stack([c.force for c in solved]),
                                              np.stack([c.stiffness for c in solved]))
        return onsets, np.asarray(force), np.asarray(slope), all(c.converged for c in solved)


def _node_build(builder: _SharedBuilder, idx: int) -> dict[str, np.ndarray]:
    """The arrays of node ``idx`` as cached: onset / depth, force, slope, converged."""
    onset, force, slope, ok = builder(idx)
    return {"onset": onset / builder.geometry[idx][0], "force": force, "slope": slope,
            "converged": np.asarray(ok, dtype=float)}


def _mirror_padded(v: np.ndarray, pad: int) -> np.ndarray:
    """s >= 0 columns padded with the last (smooth-wheel) column, then mirrored to s < 0."""
    v = np.concatenate([v, np.repeat(v[-1:], pad, axis=0)], axis=0)
    return np.concatenate([v[:0:-1], v], axis=0)


def build_family(spec: FamilySpec, material: Material = _DEFAULT_MATERIAL, cache_dir=None,
                 progress: bool = False, tol: float = 1e-8) -> FlatFamily:
    """Build (or load from the on-disk cache) every node table of ``spec``.

    Args:
        spec: a :func:`family_spec`.
        material: wheel and rail material (concrete).
        cache_dir: cache directory (see :func:`wfjax._cache.cache_directory`).
        progress: print one line to stderr per node built (cached nodes are silent).
        tol: CG tolerance of the solves.

    Returns:
        :class:`FlatFamily`.
    """
    if not kalker._is_concrete_tree(material):
        raise ValueError("build_family needs a concrete material (node tables are cached)")
    n_d, n_l = len(spec.depth_index), len(spec.length_index)
    n_s, n_t = spec.n_s, spec.n_t
    onset = np.zeros((n_d, n_l, n_s))
    force = np.zeros((n_d, n_l, n_s, n_t))
    slope = np.zeros((n_d, n_l, n_s, n_t))
    ok = True
    from .. import _cache

    paths = {idx: _cache.cache_path("family-node", _node_key(spec, idx, material, float(tol)),
                                    cache_dir) for idx in range(n_d * n_l)}
    built = {idx: _cache._read(path) for idx, path in paths.items()}
    missing = [idx for idx, arrays in built.items() if arrays is None]
    if missing:
        # Node builds are independent, and one XLA CPU computation keeps about one core busy:
        # one thread per core (XLA releases the GIL), the most expensive (deepest) first.
        missing.sort(key=lambda idx: -spec.grids[idx][0] * spec.grids[idx][1]
                     * spec.node_columns[idx])
        t0 = time.perf_counter()
        builder = _SharedBuilder(spec, missing, material, float(tol))
        if progress:
            print(f"contact family ({spec.kind}): {len(missing)} of {n_d * n_l} nodes to "
                  f"build, window sizes {builder.sizes}, planned in "
                  f"{time.perf_counter() - t0:.1f} s (their solvers compile on the core pool)",
                  file=sys.stderr, flush=True)

        def build(idx):
            t1 = time.perf_counter()
            arrays = _node_build(builder, idx)
            _cache.store(paths[idx], arrays)
            if progress:
                depth, lam, _, s = builder.geometry[idx]
                geo = f"depth {depth * 1e3:.4g} mm" + (
                    f", l/l0 {lam:.4g}" if spec.kind == "rounded" else "")
                print(f"contact family ({spec.kind}) node {idx + 1}/{n_d * n_l}: {geo}, "
                      f"{len(s)} columns: built in {time.perf_counter() - t1:.1f} s",
                      file=sys.stderr, flush=True)
            return arrays

        built.update(zip(missing, map_per_core(build, missing), strict=True))
    for idx in range(n_d * n_l):
        a = built[idx]
        n_cols = a["onset"].shape[0]
        i, j = divmod(idx, n_l)
        onset[i, j], force[i, j], slope[i, j] = (
            _mirror_padded(a[name], spec.n_half + 1 - n_cols)
            for name in ("onset", "force", "slope"))
        ok = ok and bool(a["converged"] == 1.0)
    return FlatFamily(spec, jnp.asarray(spec.c_max), to_device(onset), to_device(force),
                      to_device(slope), jnp.asarray(1.0 if ok else 0.0))

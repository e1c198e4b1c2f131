"""A parametric 3D contact law F(delta, s; depth[, length]) of new and rounded flats.

One :class:`FlatFamily` serves every flat of one kind (``"new"`` or ``"rounded"``), pair of
radii, material and element size whose depth (and, for rounded flats, length) lies in its
range: the geometry is a traced input of a pure-jnp interpolation over precomputed node tables,
so ``jit``, ``vmap`` and ``grad`` reach the depth and the length, and no table is built at
evaluation time.

Why it works: the rigid gap is self-similar
-------------------------------------------
With L = sqrt(R_W d) along x (sqrt(R_R d) across), the smooth wheel x^2/2R_W + y^2/2R_R, the
chord of a new flat d - x^2/2R_W and the cosine of a rounded flat (d/2)(1 + cos(2 pi x / l))
with l = lambda l0, l0 = sqrt(8 R_W d), all become d G(x/L, y/L; s/L, lambda). The half-space
problem is scale-invariant, so in the continuum F = E* d^(3/2) Phi(delta/d, s/L; lambda) up to
the O(d/R) difference between circles and parabolas. The node tables are therefore tabulated
on a scaled flat position sigma = s / half (half = l/2, or l0/2 for new flats), and between
nodes only the small residual dependence
(the discretisation at fixed element size, which changes h/L, and the O(d/R) terms) is left
for the depth interpolation; lambda = l/l0 stays a genuine parameter of rounded flats.

Interpolation (documented scheme)
---------------------------------
* Node lattice (global and fixed, so node tables are shared between families and calls):
  depths d_k = 1.1 mm x 2^(k / DEPTH_STEPS_PER_OCTAVE) (log-spaced; 0.1375, 0.275, 0.55, 1.1,
  2.2 mm, ...), length factors lambda_j = LENGTH_FACTOR_ORIGIN + j LENGTH_FACTOR_STEP
  (1.66, 1.86, ...). The lattice is deliberately not aligned with the paper's geometries: every
  Fig. 8 flat (0.25-2.00 mm, l = 1.76 l0) lies between nodes in depth and in length, which is
  where the family is checked against exact tables. A family holds the contiguous block of
  lattice nodes that brackets the requested geometries; an axis whose requested values all sit
  on one node has that single node.
* Every node table has the layout of :mod:`wfjax.contact.tables`: columns at whole elements
  s = j h (so the flat sits at the same sub-element phase in every column, as in the
  per-flat tables), t = sqrt(c / c_max), c = delta - onset, the same physical c_max
  (1.4 x the Hertz approach at ``max_force``) and n_t for every node.
* A query (s, d, l) reads each node at a node position s_node (Catmull-Rom over 4 of the
  node's columns) and at the same physical compression c, so the node columns combine into
  one :class:`~wfjax.contact.interpolation.Column` without resampling along t. Far from the
  flat every node is the same smooth wheel at fixed c, so the combination is exact there. (Fixed
  *scaled* compression c/d would need each node to cover its neighbours' scaled range: up to
  r^2 times the compression, and a larger grid, for a node ratio r.) Rounded flats
  (``s_map="scaled"``): the same scaled position, s_node = (s / half) half_node. New flats
  (``s_map="edges"``, see :func:`_node_position`): the physical s in a centre band
  |s| <= b0 (~2 mm), where the nearly parallel flat touches along its whole chord and the
  force falls within ~c R / (2 half) of s = 0 (0.2 mm at 30 um: a scaled position puts the
  nodes at different points of that peak), the physical offset from the chord edge within
  b1 (~5 mm) inside the edge and beyond it (the edge's transition and the smooth wheel's
  patch have physical widths), and a C1 ramp in between (s = +-half -> +-half_node).
* Along log(depth) and lambda: C1 piecewise-cubic Hermite with finite-difference node slopes
  (central differences inside, second-order one-sided differences at the end nodes; linear
  for two nodes, constant for one), over a 4-node window: it interpolates the nodes and is C1
  in the geometry, so gradients are continuous.
* Onset: computed from the traced geometry (a 1D search of the continuum rigid onset,
  cheap), by default at the 4 element-spaced positions around s and Catmull-Rom in s, which
  is what the per-flat tables do with theirs (``onset="columns"``), or at s itself
  (``onset="exact"``). Interpolating node onsets over depth was 0.9 um off near a rounded
  flat's conformal centre, where the contact stiffness is ~5e9 N/m (20 % of a 20 kN force);
  the exact onset and the table's differ by up to 0.085 um (0.75 % at 24 kN), so
  ``"columns"`` reproduces the per-flat table at node geometries to 1e-5.

Accuracy (1 mm elements, R_W = R_R = 0.45 m, the 8 depths 0.25-2.00 mm, all between depth
nodes; max relative force error against the exact per-flat tables over (delta, s), by force
band 20-50 / 50-100 / 100-300 / 300-600 kN; benchmarks/bench_family.py):

* new flats, ``s_map="edges"``: 11.9 / 3.3 / 1.9 / 0.6 % (the scaled position gave 12.6 /
  7.0 / 4.5 / 2.4 %, worst at |s| < 2 mm, where the force falls within ~c R / (2 half) of the
  centre). Worst depth 1.00 mm; 0.25-0.5 mm: 2.7 / 1.0 / 0.6 / 0.5 %.
* rounded flats, l = 1.76 l0 (between the length-factor nodes 1.66 and 1.86, so linear in
  lambda): 4.4 / 3.5 / 3.2 / 2.7 %, worst at the conformal centre and growing with the depth;
  ``min_length_nodes=3`` (adds 2.06; 15 nodes instead of 10): 3.2 / 2.1 / 1.9 / 1.4 %.
  (0.4-0.6 % at 100-300 kN was measured with lambda = 1.76 on a node.)

Both are limited by the discretisation itself. At fixed compression and flat position the
1 mm discrete force is not a smooth function of the depth: direct solves at the flat centre of
a rounded flat for 26 depths in 0.25-0.5 mm scatter about a smooth fit by +-1.1 % at 20 kN,
+-0.5 % at 100 kN (the contact edge crossing element rows), and no interpolation over depth
can follow that; a node ratio of 2 and one of sqrt(2) gave the same errors. New flats scatter
more, because a sharp chord edge bounds the patch and its sub-element phase frac(half / h)
changes with the depth: at a fixed physical s = 5 mm, 41 depths in 1.0-2.2 mm scatter about a
smooth fit by +-1.9 % at ~70 kN and +-0.5 % at ~190 kN (s = 2 mm: +-2.0 % at 35 kN, +-0.8 % at
130 kN; s = 0, where both edges bound a long strip: +-0.25 %), and at a fixed depth the force
wiggles with period h in s (1.5 mm: +-2.9 % at 50-100 kN) while a per-flat table samples that
wiggle at its own phase. The worst new-flat depth (1.00 mm) has its edges on element centres
(phase 0; the nodes' are 0.25-0.73). Tried for new flats and not kept: two depth nodes per
octave (12.1 / 3.5 / 1.9 / 0.4 %, 1.6 x the nodes); interpolating log(F + F0) (13-29 % at
F0 = 1-50 kN) or F / d^p (p = 0.25: no change; p >= 0.5 worse); node columns every h/4 (4 x the
build) read at the query's own edge phase (smooth part and wiggle separated): 1.00 mm 1.9 ->
0.9 % at 100-300 kN, but 1.5-1.75 mm worse at 20-100 kN (up to 15 % at 20-50 kN): the wiggle
has element-entry jumps that 4 samples per element do not interpolate.

Outside the family's range, traced geometry is clamped to the range (the law of the nearest
covered flat, zero gradient with respect to the clamped parameter); :func:`family_spec`
raises ``ValueError`` for concrete geometries outside the lattice.

Build and cache: each node table is built by ``lax.map`` over its columns (s >= 0, mirrored)
and a warm-started ``lax.scan`` over the compression (the per-flat builder's column routine),
and cached on disk by itself (:mod:`wfjax._cache`: atomic, verified), so
families over overlapping ranges share node tables. Nodes are built concurrently, one thread
per CPU core (deepest first).
"""

from __future__ import annotations

import functools
import math
import sys
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._parallel import core_pool, map_per_core
from .._xla import to_device
from ..params import MAX_FLAT_DEPTH, Flat, Material
from . import geometry3d, influence, interpolation, kalker, table_spec, tables, windows

__all__ = ["FamilySpec", "FlatFamily", "family_spec", "build_family", "family_column",
           "family_force", "DEPTH_STEPS_PER_OCTAVE", "LENGTH_FACTOR_ORIGIN",
           "LENGTH_FACTOR_STEP", "FAMILY_KINDS"]

_DEFAULT_MATERIAL = Material()
FAMILY_KINDS = ("new", "rounded")
DEPTH_REFERENCE = 1.1e-3  # m; lattice depth of index 0 (nodes 0.1375, 0.275, 0.55, 1.1, 2.2 mm)
DEPTH_STEPS_PER_OCTAVE = 1  # depth nodes per factor 2 in depth
MIN_DEPTH = 0.05e-3  # m; shallowest lattice node allowed
LENGTH_FACTOR_ORIGIN = 1.66  # lambda = l / l0 of lattice index 0
LENGTH_FACTOR_STEP = 0.2
MIN_LENGTH_FACTOR = math.pi / 2  # rounded flats: l >= pi/2 l0
MAX_LENGTH_FACTOR = 8.0
ONSET_MODES = ("columns", "exact")
S_MAPS = ("scaled", "edges")
CENTRE_BAND = 2e-3  # m; "edges" map: physical s for |s| <= this (capped at 0.15 x smallest half)
EDGE_BAND = 5e-3  # m; "edges" map: physical edge offset within this of the edge (<= 0.3 half)
_RAMP_ROUNDING = 0.25  # "edges" map: fraction of the ramp at each end rounded (C1)
_ON_NODE = 1e-9  # relative distance below which a requested value is "on" a node
# Part of every node's cache key: raise it when the node builder's results change, so a cache
# written by an older builder of the same wfjax version is never served (2: issue 20's
# faster CG, forces within 1e-9 of revision 1's).
NODE_BUILDER_REVISION = 2


class FamilySpec(NamedTuple):
    """Static layout of a :class:`FlatFamily` (hashable; concrete numbers).

    Attributes:
        kind: ``"new"`` or ``"rounded"``.
        wheel_radius, rail_head_radius: R_W, R_R [m].
        element_size: square contact element side [m].
        max_force: largest force covered [N] (sets c_max).
        c_max: compression of the last t node [m] (every node).
        n_t: nodes along t = sqrt(c / c_max).
        d_sigma: target column spacing in sigma = s / half (each node rounds it to a whole
            number of elements, at least one); 0: one element for every node (default).
        n_half: columns on each side of sigma = 0 (n_s = 2 n_half + 1).
        depth_index: lattice indices k of the depth nodes (contiguous, increasing).
        length_index: lattice indices j of the length-factor nodes (``(0,)`` for new flats,
            where it is unused).
        grids: (nx, ny) of each node's contact grid, depth-major (len = n_depth x n_length).
        node_columns: solved columns (s >= 0) of each node, same order.
        node_steps: column spacing of each node in elements (an integer, so every column
            sits at s = multiple of the element size like the per-flat tables' columns: the
            flat then has the same position relative to the grid in every column, and the
            discrete solution's sub-element wobble in s is sampled at the same phase).
        onset: ``"columns"`` (default): the exact continuum onset of the traced flat at the
            4 element-spaced positions around s, Catmull-Rom in s, as the per-flat tables
            interpolate theirs; ``"exact"``: the exact onset at s.
        s_map: how a query position s is read on each node: ``"scaled"`` (rounded flats'
            default): s_node = (s / half) half_node; ``"edges"`` (new flats' default): the
            physical s in the centre band |s| <= centre_band, the physical offset from the
            chord edge for |s| >= half - edge_band, a C1 ramp between (see :func:`_node_position`).
        centre_band, edge_band: band widths [m] of ``"edges"`` (0 for ``"scaled"``).
    """

    kind: str
    wheel_radius: float
    rail_head_radius: float
    element_size: float
    max_force: float
    c_max: float
    n_t: int
    d_sigma: float
    n_half: int
    depth_index: tuple
    length_index: tuple
    grids: tuple
    node_columns: tuple
    node_steps: tuple
    onset: str
    s_map: str = "scaled"
    centre_band: float = 0.0
    edge_band: float = 0.0

    @property
    def depths(self) -> np.ndarray:
        """[n_depth] node depths [m]."""
        return np.array([lattice_depth(k) for k in self.depth_index])

    @property
    def length_factors(self) -> np.ndarray:
        """[n_length] node length factors lambda = l / l0 (rounded flats)."""
        return np.array([lattice_length_factor(j) for j in self.length_index])

    @property
    def depth_range(self) -> tuple[float, float]:
        """(min, max) depth [m] covered."""
        d = self.depths
        return float(d[0]), float(d[-1])

    @property
    def length_factor_range(self) -> tuple[float, float]:
        """(min, max) lambda covered (rounded flats)."""
        lam = self.length_factors
        return float(lam[0]), float(lam[-1])

    @property
    def nodes(self) -> list[tuple[float, float]]:
        """(depth [m], lambda) of every node, depth-major."""
        return [(float(d), float(lam)) for d in self.depths for lam in self.length_factors]

    @property
    def n_s(self) -> int:
        """Stored columns per node (mirrored, padded with the smooth-wheel end column)."""
        return 2 * self.n_half + 1

    @property
    def node_half(self) -> np.ndarray:
        """[n_depth, n_length] half [m] of each node (l/2, or l0/2 of a new flat)."""
        out = [_node_half(self.kind, d, _node_flat(self.kind, d, lam, self.wheel_radius).length,
                          self.wheel_radius) for d, lam in self.nodes]
        return np.array(out).reshape(len(self.depth_index), len(self.length_index))

    @property
    def column_scale(self) -> np.ndarray:
        """[n_depth, n_length] half / (column spacing) of each node: column index per sigma."""
        out = []
        for idx, step in enumerate(self.node_steps):
            k = self.depth_index[idx // len(self.length_index)]
            j = self.length_index[idx % len(self.length_index)]
            depth = lattice_depth(k)
            flat = _node_flat(self.kind, depth, lattice_length_factor(j), self.wheel_radius)
            half = _node_half(self.kind, depth, flat.length, self.wheel_radius)
            out.append(half / (step * self.element_size))
        return np.array(out).reshape(len(self.depth_index), len(self.length_index))


@functools.partial(jax.tree_util.register_dataclass, data_fields=[
    "c_max", "onset", "force", "slope", "converged"], meta_fields=["spec"])
class FlatFamily:
    """Node tables of a parametric contact law (a pytree; ``spec`` is static).

    Attributes:
        spec: the :class:`FamilySpec`.
        c_max: compression of the last t node [m] (scalar).
        onset: [n_depth, n_length, n_s] rigid contact onset / node depth (dimensionless) of
            the node columns (informative: the evaluation computes the onset from the
            traced geometry).
        force: [n_depth, n_length, n_s, n_t] force [N] at c = c_max (j / (n_t - 1))^2.
        slope: [n_depth, n_length, n_s, n_t] dF/du [N] per t node index u.
        converged: 1.0 when every solve of every node converged, else 0.0 (scalar).
    """

    def __init__(self, spec: FamilySpec, c_max, onset, force, slope, converged):
        self.spec = spec
        self.c_max = c_max
        self.onset = onset
        self.force = force
        self.slope = slope
        self.converged = converged


def lattice_depth(k: int) -> float:
    """Depth [m] of lattice index ``k``: 1.1 mm x 2^(k / DEPTH_STEPS_PER_OCTAVE)."""
    return DEPTH_REFERENCE * 2.0 ** (k / DEPTH_STEPS_PER_OCTAVE)


def lattice_length_factor(j: int) -> float:
    """Length factor lambda = l / l0 of lattice index ``j``."""
    return LENGTH_FACTOR_ORIGIN + j * LENGTH_FACTOR_STEP


def _depth_coordinate(depth):
    return jnp.log(depth / DEPTH_REFERENCE) / math.log(2.0) * DEPTH_STEPS_PER_OCTAVE


def _bracket(coord) -> tuple[int, ...]:
    """Contiguous lattice indices covering the lattice coordinates ``coord``."""
    lo, hi = float(np.min(coord)), float(np.max(coord))
    k_lo, k_hi = math.floor(lo + _ON_NODE), math.ceil(hi - _ON_NODE)
    if abs(lo - round(lo)) < _ON_NODE:
        k_lo = round(lo)
    if abs(hi - round(hi)) < _ON_NODE:
        k_hi = round(hi)
    return tuple(range(k_lo, max(k_hi, k_lo) + 1))


def _half_scale(kind: str, depth, length, wheel_radius):
    """half [m]: l/2 of a rounded flat, l0/2 = sqrt(2 R_W d) of a new flat (traceable)."""
    if kind == "rounded":
        return length / 2
    return jnp.sqrt(2 * wheel_radius * depth)


def _node_half(kind: str, depth: float, length: float, wheel_radius: float) -> float:
    """:func:`_half_scale` of concrete numbers (a Python float, also under tracing)."""
    return length / 2 if kind == "rounded" else math.sqrt(2 * wheel_radius * depth)


def _node_flat(kind: str, depth: float, length_factor: float, wheel_radius: float) -> Flat:
    l0 = math.sqrt(8 * wheel_radius * depth)
    if kind == "rounded":
        return Flat("rounded", depth=depth, length=length_factor * l0,
                    wheel_radius=wheel_radius)
    return Flat("new", depth=depth, length=l0, wheel_radius=wheel_radius)


def family_spec(kind: str, depths, length_factors=None, wheel_radius: float = 0.45,
                rail_head_radius: float = 0.45, material: Material = _DEFAULT_MATERIAL,
                element_size: float = 1e-3, max_force: float = 600e3, n_t: int = 16,
                d_sigma: float = 0.0, onset: str = "columns", s_map: str | None = None,
                centre_band: float | None = None, edge_band: float | None = None,
                min_length_nodes: int = 2) -> FamilySpec:
    """Choose the lattice nodes and layout of a family covering the given geometries.

    Args:
        kind: ``"new"`` or ``"rounded"``.
        depths: depths [m] to cover (any shape; their range is covered).
        length_factors: lambda = l / l0 to cover (rounded flats; required), l0 = sqrt(8 R_W d).
        wheel_radius, rail_head_radius: R_W, R_R [m].
        material: wheel and rail material (sizes the compression range and grids).
        element_size: square contact element side [m].
        max_force: largest force to cover [N]; c_max = 1.4 x the Hertz approach at it.
        n_t: nodes along t = sqrt(c / c_max).
        d_sigma: column spacing in sigma = s / half, rounded per node to whole elements;
            0 (default): every node's columns one element apart, like the per-flat tables
            (measured at a node, 1 mm elements, 1 mm rounded flat: 2-element columns are
            0.5 % off the per-flat table at 100-600 kN, 1-element columns 0.000 %).
        onset: ``"columns"`` or ``"exact"`` (see :class:`FamilySpec`).
        s_map: ``"scaled"`` or ``"edges"`` (see :class:`FamilySpec`); default ``"edges"``
            for new flats, ``"scaled"`` for rounded flats.
        centre_band, edge_band: band widths [m] of ``"edges"``; default CENTRE_BAND and
            EDGE_BAND, capped at 0.15 and 0.3 x the smallest node half (their sum must stay
            below 0.6 x it).
        min_length_nodes: rounded flats whose length factors need two or more lattice nodes
            get at least this many (extended upwards, then downwards, within [pi/2,
            MAX_LENGTH_FACTOR]). With two the interpolation in lambda is linear: 1 mm, 0.275
            mm depth (a node), lambda = 1.76 between 1.66 and 1.86: 2.2 / 2.0 / 1.4 / 0.7 %
            at 20-50 / 50-100 / 100-300 / 300-600 kN, worst at the conformal centre; with a
            third node (2.06): 1.0 / 1.0 / 0.5 / 0.2 %, for 1.5 x the nodes.

    Returns:
        :class:`FamilySpec`.

    Raises:
        ValueError: unknown kind, depths outside [MIN_DEPTH, MAX_FLAT_DEPTH] (after rounding
            out to the lattice), length factors outside [pi/2, MAX_LENGTH_FACTOR], missing
            length factors for rounded flats, bad element size or n_t.
    """
    if kind not in FAMILY_KINDS:
        raise ValueError(f"kind must be one of {FAMILY_KINDS}, got {kind!r}")
    h = float(element_size)
    if not math.isfinite(h) or h <= 0:
        raise ValueError(f"element_size must be > 0 m, got {element_size!r}")
    if int(n_t) < 4:
        raise ValueError(f"n_t must be >= 4, got {n_t!r}")
    d = np.asarray(depths, dtype=float).ravel()
    if d.size == 0 or not np.all(np.isfinite(d)):
        raise ValueError(f"depths must be finite numbers [m], got {depths!r}")
    if np.any(d < MIN_DEPTH) or np.any(d > MAX_FLAT_DEPTH):
        raise ValueError(
            f"depths must be in [{MIN_DEPTH * 1e3:g}, {MAX_FLAT_DEPTH * 1e3:g}] mm, got "
            f"{d.min() * 1e3:g} to {d.max() * 1e3:g} mm")
    depth_index = _bracket(np.asarray(_depth_coordinate(d)))
    if lattice_depth(depth_index[0]) < MIN_DEPTH * (1 - 1e-12) or \
            lattice_depth(depth_index[-1]) > MAX_FLAT_DEPTH * (1 + 1e-12) * 2 ** (
                1 / DEPTH_STEPS_PER_OCTAVE):
        raise ValueError(
            f"depths {d.min() * 1e3:g} to {d.max() * 1e3:g} mm need lattice nodes outside "
            f"[{MIN_DEPTH * 1e3:g}, {MAX_FLAT_DEPTH * 1e3:g}] mm")
    if kind == "rounded":
        if length_factors is None:
            raise ValueError("length_factors (lambda = l / l0) are required for rounded flats")
        lam = np.asarray(length_factors, dtype=float).ravel()
        if lam.size == 0 or not np.all(np.isfinite(lam)):
            raise ValueError(f"length_factors must be finite, got {length_factors!r}")
        if np.any(lam < MIN_LENGTH_FACTOR - 1e-12) or np.any(lam > MAX_LENGTH_FACTOR):
            raise ValueError(
                f"length_factors (l / l0) must be in [pi/2 = {MIN_LENGTH_FACTOR:.4f}, "
                f"{MAX_LENGTH_FACTOR:g}], got {lam.min():.4g} to {lam.max():.4g}")
        length_index = _bracket((lam - LENGTH_FACTOR_ORIGIN) / LENGTH_FACTOR_STEP)
        up = True
        while 1 < len(length_index) < int(min_length_nodes):
            hi, lo = length_index[-1] + 1, length_index[0] - 1
            if up and lattice_length_factor(hi) <= MAX_LENGTH_FACTOR:
                length_index = length_index + (hi,)
            elif lattice_length_factor(lo) >= MIN_LENGTH_FACTOR - 1e-12:
                length_index = (lo,) + length_index
            elif lattice_length_factor(hi) <= MAX_LENGTH_FACTOR:
                length_index = length_index + (hi,)
            else:
                break
            up = not up
    else:
        if length_factors is not None:
            raise ValueError("length_factors apply to rounded flats only (new flats: "
                             "l0 = sqrt(8 R_W d) follows from the depth)")
        length_index = (0,)
    ds = float(d_sigma)
    if not math.isfinite(ds) or ds < 0:
        raise ValueError(f"d_sigma must be >= 0, got {d_sigma!r}")
    if onset not in ONSET_MODES:
        raise ValueError(f"onset must be one of {ONSET_MODES}, got {onset!r}")
    if s_map is None:
        s_map = "edges" if kind == "new" else "scaled"
    if s_map not in S_MAPS:
        raise ValueError(f"s_map must be one of {S_MAPS}, got {s_map!r}")
    _, _, d_hertz, _ = geometry3d.elliptic_hertz(max_force, wheel_radius, rail_head_radius,
                                             material)
    c_max = 1.4 * d_hertz
    grids, columns, steps = [], [], []
    for k in depth_index:
        for j in length_index:
            depth = lattice_depth(k)
            lam_j = lattice_length_factor(j)
            flat = _node_flat(kind, depth, lam_j, wheel_radius)
            x, y = geometry3d.contact_grid(flat, wheel_radius, rail_head_radius, material,
                                       max_compression=c_max, max_force=max_force,
                                       element_size=h)
            grids.append((len(x), len(y)))
            half = _node_half(kind, depth, flat.length, wheel_radius)
            # Beyond half + sqrt(2 R_W c_max) the flat is outside every rigid overlap: the
            # column is the smooth wheel (as in table_spec.table_spec).
            reach = half + math.sqrt(2 * float(wheel_radius) * c_max) + 2 * h
            step = max(1, round(ds * half / h)) if ds > 0 else 1
            steps.append(step)
            columns.append(math.ceil(reach / (step * h)) + 1)
    b0 = b1 = 0.0
    if s_map == "edges":
        half_min = min(_node_half(kind, lattice_depth(k), _node_flat(
            kind, lattice_depth(k), lattice_length_factor(j), wheel_radius).length,
            wheel_radius) for k in depth_index for j in length_index)
        b0 = min(CENTRE_BAND, 0.15 * half_min) if centre_band is None else float(centre_band)
        b1 = min(EDGE_BAND, 0.3 * half_min) if edge_band is None else float(edge_band)
        if not (b0 >= 0 and b1 >= 0 and b0 + b1 < 0.6 * half_min):
            raise ValueError(f"centre_band + edge_band must be in [0, 0.6 x the smallest node "
                             f"half = {0.6 * half_min * 1e3:.3g} mm), got {b0!r}, {b1!r}")
    return FamilySpec(kind=kind, wheel_radius=float(wheel_radius),
                      rail_head_radius=float(rail_head_radius), element_size=h,
                      max_force=float(max_force), c_max=float(c_max), n_t=int(n_t),
                      d_sigma=ds, n_half=max(columns) - 1, depth_index=depth_index,
                      length_index=length_index, grids=tuple(grids),
                      node_columns=tuple(columns), node_steps=tuple(steps),
                      onset=onset, s_map=s_map, centre_band=float(b0), edge_band=float(b1))


FAMILY_WINDOW_SIZES = 6  # window sizes of a family build (one compiled solver each, shared)


def _node_geometry(spec: FamilySpec, idx: int):
    """(depth [m], l / l0, flat, s [n_cols] m) of node ``idx``: columns s_j = j step h >= 0
    (mirrored by build_family)."""
    n_l = len(spec.length_index)
    k, j = spec.depth_index[idx // n_l], spec.length_index[idx % n_l]
    depth, lam = lattice_depth(k), lattice_length_factor(j)
    flat = _node_flat(spec.kind, depth, lam, spec.wheel_radius)
    s = np.arange(spec.node_columns[idx]) * spec.node_steps[idx] * spec.element_size
    return depth, lam, flat, s


def _node_key(spec: FamilySpec, idx: int, material: Material, tol: float) -> dict:
    depth, lam, _, _ = _node_geometry(spec, idx)
    nx, ny = spec.grids[idx]
    return {"kind": spec.kind, "depth": depth,
            "length_factor": lam if spec.kind == "rounded" else None,
            "wheel_radius": spec.wheel_radius, "rail_head_radius": spec.rail_head_radius,
            "element_size": spec.element_size, "c_max": spec.c_max, "n_t": spec.n_t,
            "step": spec.node_steps[idx], "n_cols": spec.node_columns[idx], "nx": nx, "ny": ny,
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
            element_size=spec.element_size, s_max=(self.n - 1) * spec.element_size,
            n_s=self.n, c_max=spec.c_max, n_t=spec.n_t, symmetric=True,
            wheel_radius=spec.wheel_radius, rail_head_radius=spec.rail_head_radius)
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


# ----------------------------------------------------------------------------------------
# Evaluation (pure jnp)
# ----------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=32)
def _slope_matrix(n: int) -> np.ndarray:
    """[n, n] node slopes m = D f of unit-spaced node values (finite differences)."""
    D = np.zeros((n, n))
    if n == 2:
        D[0, :2] = D[1, :2] = (-1.0, 1.0)
    elif n >= 3:
        D[0, :3] = (-1.5, 2.0, -0.5)
        D[-1, -3:] = (0.5, -2.0, 1.5)
        for i in range(1, n - 1):
            D[i, i - 1], D[i, i + 1] = -0.5, 0.5
    return D


def _axis_weights(u, n: int):
    """(indices [m], weights [m]) of the C1 cubic Hermite over n unit-spaced nodes at u.

    u is clamped to [0, n - 1]. m = min(n, 4): a window of 4 nodes holds every node the
    interval's two Hermite slopes use.
    """
    if n == 1:
        return jnp.zeros((1,), jnp.int32), jnp.ones((1,), jnp.result_type(u, float))
    u = jnp.clip(u, 0.0, n - 1.0)
    i = jnp.clip(jnp.floor(u), 0, n - 2).astype(jnp.int32)
    v = u - i
    v2, v3 = v * v, v * v * v
    h00, h10, h01, h11 = 2 * v3 - 3 * v2 + 1, v3 - 2 * v2 + v, -2 * v3 + 3 * v2, v3 - v2
    m = min(n, 4)
    idx = jnp.clip(i - 1, 0, n - m) + jnp.arange(m)
    D = jnp.asarray(_slope_matrix(n))
    w = (h00 * (idx == i) + h01 * (idx == i + 1) + h10 * D[i, idx] + h11 * D[i + 1, idx])
    return idx, w


def _geometry(spec: FamilySpec, depth, length):
    """Clamped (depth, half, lattice coordinates u_depth, u_length) of a traced geometry.

    lambda = l / l0 is taken from the given depth, then depth and lambda are clamped to the
    family's range separately (the nearest covered flat in (log d, lambda)).
    """
    d_lo, d_hi = spec.depth_range
    depth = jnp.asarray(depth, dtype=float)
    if spec.kind == "rounded":
        if length is None:
            raise ValueError("family_column needs the length of a rounded flat")
        lam_lo, lam_hi = spec.length_factor_range
        safe = jnp.maximum(depth, d_lo)
        lam = jnp.clip(jnp.asarray(length, dtype=float) / jnp.sqrt(8 * spec.wheel_radius * safe),
                       lam_lo, lam_hi)
    depth = jnp.clip(depth, d_lo, d_hi)
    u_d = _depth_coordinate(depth) - spec.depth_index[0]
    if spec.kind == "rounded":
        half = lam * jnp.sqrt(8 * spec.wheel_radius * depth) / 2
        u_l = (lam - LENGTH_FACTOR_ORIGIN) / LENGTH_FACTOR_STEP - spec.length_index[0]
    else:
        half = _half_scale("new", depth, None, spec.wheel_radius)
        u_l = jnp.zeros_like(depth)
    return depth, half, u_d, u_l


def _ramp(x):
    """C1 ramp 0 -> 1 on [0, 1] (0 below, 1 above): linear, rounded by quadratics over the
    first and last _RAMP_ROUNDING of the interval; slope at most 1 / (1 - _RAMP_ROUNDING)."""
    e = _RAMP_ROUNDING
    x = jnp.clip(x, 0.0, 1.0)
    k = 1.0 / (2 * e * (1 - e))
    return jnp.where(x < e, k * x * x, jnp.where(x > 1 - e, 1 - k * (1 - x) ** 2,
                                                 (x - e / 2) / (1 - e)))


def _node_position(spec: FamilySpec, s, half, node_half):
    """Position [m] at which a node of half ``node_half`` is read for the query (s, half).

    ``"scaled"``: s node_half / half (the same scaled position sigma = s / half).
    ``"edges"`` (new flats): s + (node_half - half) B((|s| - b0) / (half - b1 - b0)) sign(s),
    B the C1 ramp of :func:`_ramp`: the physical s in the centre band |s| <= b0, where the
    nearly parallel flat touches along its whole chord and the force falls within
    ~c R / (2 half) of s = 0; the physical offset from the chord edge for |s| >= half - b1
    (the edge's elastic transition and the smooth wheel's contact patch have physical sizes,
    independent of the depth); s = +-half -> +-node_half.
    """
    if spec.s_map == "scaled":
        return s / half * node_half
    b0, b1 = spec.centre_band, spec.edge_band
    a = jnp.abs(s)
    return s + jnp.sign(s) * (node_half - half) * _ramp((a - b0) / (half - b1 - b0))


def _exact_onset(spec: FamilySpec, s, depth, half, n_coarse: int = 129, n_fine: int = 65):
    """Continuum rigid contact onset min_x' gap(x', 0; s) [m] of the traced flat.

    The minimiser satisfies x'^2 / 2R_W <= gap(x') <= gap(0) <= d, so it lies in
    |x'| <= sqrt(2 R_W d): a grid of ``n_coarse`` points there, refined on ``n_fine`` points
    across two coarse steps around its minimiser, plus the kinks of a new flat's chord ends.
    Grid minimisers are held fixed for the gradient (envelope theorem); the kinks move with the
    depth and keep their gradient.
    """
    from ..model.geometry import profile_deviation

    rw = spec.wheel_radius
    if spec.kind == "rounded":
        flat = Flat("rounded", depth=depth, length=2 * half, wheel_radius=rw)
    else:
        flat = Flat("new", depth=depth, length=2 * half, wheel_radius=rw)

    def g1d(x):
        return rw - jnp.sqrt(rw**2 - x**2) + profile_deviation(flat, x + s)

    window = jax.lax.stop_gradient(jnp.sqrt(2 * rw * depth))
    xs = window * jnp.linspace(-1.0, 1.0, n_coarse)
    step = 2 * window / (n_coarse - 1)
    x0 = xs[jnp.argmin(g1d(xs))]
    xf = jax.lax.stop_gradient(x0 + step * jnp.linspace(-1.0, 1.0, n_fine))
    candidates = [xf]
    if spec.kind == "new":
        edge = rw * jnp.arccos(1.0 - depth / rw)
        candidates.append(jnp.clip(jnp.stack([edge - s, -edge - s]), -window, window))
    return jnp.min(g1d(jnp.concatenate(candidates)))


def family_column(family: FlatFamily, s, depth, length=None) -> interpolation.Column:
    """The compression column at flat position ``s`` [m] of the flat (depth, length).

    ``interpolation.column_force(family_column(family, s, depth, length), delta)`` is the force.
    Pure jnp: ``jit``/``vmap``/``grad`` with respect to s, depth [m] and length [m] (rounded
    flats; ignored for new flats). Geometry outside the family's range is clamped to it:
    lambda = length / l0(depth) and the depth are each clamped to their node range (zero
    gradient beyond); beyond the tabulated s range the end columns (smooth wheel) apply.

    Returns:
        :class:`wfjax.contact.interpolation.Column` (onset [m], c_max [m], force [n_t] N,
        slope [n_t] N).
    """
    spec = family.spec
    depth, half, u_d, u_l = _geometry(spec, depth, length)
    n_d, n_l, n_s = family.onset.shape
    i_d, w_d = _axis_weights(u_d, n_d)
    i_l, w_l = _axis_weights(u_l, n_l)
    # Each node at its own position (:func:`_node_position`); column index = position / spacing.
    node_half = jnp.asarray(spec.node_half)[i_d[:, None], i_l[None, :]]
    scale = jnp.asarray(spec.column_scale)[i_d[:, None], i_l[None, :]] / node_half
    u_s = jnp.clip(_node_position(spec, s, half, node_half) * scale + spec.n_half, 0.0,
                   n_s - 1.0)  # [m_d, m_l]
    c = jnp.clip(jnp.floor(u_s), 0, n_s - 2).astype(jnp.int32)
    # Catmull-Rom weights of columns c-1, c, c+1, c+2 (clamped at the ends): [m_d, m_l, 4].
    w_s = jnp.moveaxis(interpolation.catmull_rom_weights(u_s - c), 0, -1)
    i_s = jnp.clip(c[..., None] + jnp.arange(-1, 3), 0, n_s - 1)
    ix = (i_d[:, None, None], i_l[None, :, None], i_s)
    if spec.onset == "columns":
        h = spec.element_size
        u = s / h
        i0 = jnp.floor(u)
        wo = interpolation.catmull_rom_weights(u - i0)
        sj = (i0 + jnp.arange(-1, 3)) * h
        onset = jnp.sum(wo * jax.vmap(lambda si: _exact_onset(spec, si, depth, half))(sj))
    else:
        onset = _exact_onset(spec, s, depth, half)
    force = jnp.einsum("i,j,ijk,ijkt->t", w_d, w_l, w_s, family.force[ix])
    slope = jnp.einsum("i,j,ijk,ijkt->t", w_d, w_l, w_s, family.slope[ix])
    return interpolation.Column(onset=onset, c_max=family.c_max, force=force, slope=slope)


def family_force(family: FlatFamily, delta, s, depth, length=None):
    """Contact force F [N] at approach ``delta`` [m], flat position ``s`` [m] of the flat
    (depth [m], length [m]); ``column_force(family_column(...), delta)``. Scalars in, scalar
    out (``vmap`` for batches)."""
    return interpolation.column_force(family_column(family, s, depth, length), delta)

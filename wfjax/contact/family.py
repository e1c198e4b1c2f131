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

import jax
import jax.numpy as jnp
import numpy as np

from ..params import Flat
from . import interpolation
from .family_spec import LENGTH_FACTOR_ORIGIN, LENGTH_FACTOR_STEP, FamilySpec, depth_coordinate

__all__ = ["FlatFamily", "family_column", "family_force"]

_RAMP_ROUNDING = 0.25  # "edges" map: fraction of the ramp at each end rounded (C1)


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


def _half_scale(kind: str, depth, length, wheel_radius):
    """half [m]: l/2 of a rounded flat, l0/2 = sqrt(2 R_W d) of a new flat (traceable)."""
    if kind == "rounded":
        return length / 2
    return jnp.sqrt(2 * wheel_radius * depth)


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
    u_d = depth_coordinate(depth) - spec.depth_index[0]
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
    position = interpolation.column_coordinate(_node_position(spec, s, half, node_half),
                                               spec.stretch)
    u_s = jnp.clip(position * scale + spec.n_half, 0.0, n_s - 1.0)  # [m_d, m_l]
    c = jnp.clip(jnp.floor(u_s), 0, n_s - 2).astype(jnp.int32)
    # Catmull-Rom weights of columns c-1, c, c+1, c+2 (clamped at the ends): [m_d, m_l, 4].
    w_s = jnp.moveaxis(interpolation.catmull_rom_weights(u_s - c), 0, -1)
    i_s = jnp.clip(c[..., None] + jnp.arange(-1, 3), 0, n_s - 1)
    ix = (i_d[:, None, None], i_l[None, :, None], i_s)
    if spec.onset == "columns":
        h = spec.element_size
        u = interpolation.column_coordinate(s, spec.stretch) / h
        i0 = jnp.floor(u)
        wo = interpolation.catmull_rom_weights(u - i0)
        sj = (i0 + jnp.arange(-1, 3)) * h
        if spec.stretch:
            sj = interpolation.column_positions(sj, jnp.asarray(spec.stretch))
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

"""The lattice of a :class:`~wfjax.contact.family.FlatFamily`'s nodes (log-spaced depths,
linear length factors) and :func:`family_spec`, which picks the block of nodes and the grids that
cover the requested geometries (the scheme is described in :mod:`wfjax.contact.family`)."""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from ..params import MAX_FLAT_DEPTH, Flat, Material
from . import geometry3d
from .interpolation import column_coordinate
from .table_spec import column_stretch

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


_ON_NODE = 1e-9  # relative distance below which a requested value is "on" a node


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
        node_steps: column spacing of each node in elements, in the column coordinate (an
            integer, so every column sits where a per-flat table's does: the flat then has
            the same position relative to the grid, and the discrete solution's sub-element
            wobble in s is sampled at the same phase).
        onset: ``"columns"`` (default): the exact continuum onset of the traced flat at the
            4 element-spaced positions around s, Catmull-Rom in s, as the per-flat tables
            interpolate theirs; ``"exact"``: the exact onset at s.
        s_map: how a query position s is read on each node: ``"scaled"`` (rounded flats'
            default): s_node = (s / half) half_node; ``"edges"`` (new flats' default): the
            physical s in the centre band |s| <= centre_band, the physical offset from the
            chord edge for |s| >= half - edge_band, a C1 ramp between (see :func:`_node_position`).
        centre_band, edge_band: band widths [m] of ``"edges"`` (0 for ``"scaled"``).
        stretch: L [m] of the nodes' column coordinate: the columns are uniform in
            :func:`wfjax.contact.interpolation.column_coordinate` of the node position, as
            a per-flat table's (:func:`wfjax.contact.table_spec.column_stretch`).
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
    stretch: float = 0.0

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
        out = [_node_half(self.kind, d, node_flat(self.kind, d, lam, self.wheel_radius).length,
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
            flat = node_flat(self.kind, depth, lattice_length_factor(j), self.wheel_radius)
            half = _node_half(self.kind, depth, flat.length, self.wheel_radius)
            out.append(half / (step * self.element_size))
        return np.array(out).reshape(len(self.depth_index), len(self.length_index))


def lattice_depth(k: int) -> float:
    """Depth [m] of lattice index ``k``: 1.1 mm x 2^(k / DEPTH_STEPS_PER_OCTAVE)."""
    return DEPTH_REFERENCE * 2.0 ** (k / DEPTH_STEPS_PER_OCTAVE)


def lattice_length_factor(j: int) -> float:
    """Length factor lambda = l / l0 of lattice index ``j``."""
    return LENGTH_FACTOR_ORIGIN + j * LENGTH_FACTOR_STEP


def depth_coordinate(depth):
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


def _node_half(kind: str, depth: float, length: float, wheel_radius: float) -> float:
    """:func:`_half_scale` of concrete numbers (a Python float, also under tracing)."""
    return length / 2 if kind == "rounded" else math.sqrt(2 * wheel_radius * depth)


def node_flat(kind: str, depth: float, length_factor: float, wheel_radius: float) -> Flat:
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
    depth_index = _depth_nodes(depths)
    length_index = _length_nodes(kind, length_factors, min_length_nodes)
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
    nodes = [(lattice_depth(k), lattice_length_factor(j))
             for k in depth_index for j in length_index]
    grids, columns, steps = zip(*(
        _node_layout(kind, depth, lam, wheel_radius, rail_head_radius, material, c_max,
                     max_force, h, ds) for depth, lam in nodes), strict=True)
    b0 = b1 = 0.0
    if s_map == "edges":
        b0, b1 = _edge_bands(kind, nodes, wheel_radius, centre_band, edge_band)
    return FamilySpec(kind=kind, wheel_radius=float(wheel_radius),
                      rail_head_radius=float(rail_head_radius), element_size=h,
                      max_force=float(max_force), c_max=float(c_max), n_t=int(n_t),
                      d_sigma=ds, n_half=max(columns) - 1, depth_index=depth_index,
                      length_index=length_index, grids=tuple(grids),
                      node_columns=tuple(columns), node_steps=tuple(steps),
                      onset=onset, s_map=s_map, centre_band=float(b0), edge_band=float(b1),
                      stretch=column_stretch(kind))


def _depth_nodes(depths) -> tuple[int, ...]:
    """Lattice depth indices bracketing ``depths`` [m] (checked against the lattice's range)."""
    d = np.asarray(depths, dtype=float).ravel()
    if d.size == 0 or not np.all(np.isfinite(d)):
        raise ValueError(f"depths must be finite numbers [m], got {depths!r}")
    if np.any(d < MIN_DEPTH) or np.any(d > MAX_FLAT_DEPTH):
        raise ValueError(
            f"depths must be in [{MIN_DEPTH * 1e3:g}, {MAX_FLAT_DEPTH * 1e3:g}] mm, got "
            f"{d.min() * 1e3:g} to {d.max() * 1e3:g} mm")
    depth_index = _bracket(np.asarray(depth_coordinate(d)))
    if lattice_depth(depth_index[0]) < MIN_DEPTH * (1 - 1e-12) or \
            lattice_depth(depth_index[-1]) > MAX_FLAT_DEPTH * (1 + 1e-12) * 2 ** (
                1 / DEPTH_STEPS_PER_OCTAVE):
        raise ValueError(
            f"depths {d.min() * 1e3:g} to {d.max() * 1e3:g} mm need lattice nodes outside "
            f"[{MIN_DEPTH * 1e3:g}, {MAX_FLAT_DEPTH * 1e3:g}] mm")
    return depth_index


def _length_nodes(kind: str, length_factors, min_length_nodes: int) -> tuple[int, ...]:
    """Lattice length-factor indices bracketing ``length_factors`` (lambda = l / l0) of rounded
    flats, widened to ``min_length_nodes`` when more than one is needed; (0,) for new flats."""
    if kind != "rounded":
        if length_factors is not None:
            raise ValueError("length_factors apply to rounded flats only (new flats: "
                             "l0 = sqrt(8 R_W d) follows from the depth)")
        return (0,)
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
    return length_index


def _node_layout(kind: str, depth: float, lam: float, wheel_radius, rail_head_radius,
                 material: Material, c_max: float, max_force: float, h: float, ds: float):
    """One lattice node's contact grid (nx, ny), column count and column step [elements]."""
    flat = node_flat(kind, depth, lam, wheel_radius)
    x, y = geometry3d.contact_grid(flat, wheel_radius, rail_head_radius, material,
                                   max_compression=c_max, max_force=max_force, element_size=h)
    half = _node_half(kind, depth, flat.length, wheel_radius)
    # Beyond half + sqrt(2 R_W c_max) the flat is outside every rigid overlap: the column is
    # the smooth wheel (as in table_spec.table_spec).
    reach = half + math.sqrt(2 * float(wheel_radius) * c_max) + 2 * h
    step = max(1, round(ds * half / h)) if ds > 0 else 1
    n_cols = math.ceil(column_coordinate(reach, column_stretch(kind)) / (step * h)) + 1
    return (len(x), len(y)), n_cols, step


def _edge_bands(kind: str, nodes, wheel_radius, centre_band, edge_band) -> tuple[float, float]:
    """The ``"edges"`` map's centre and edge band widths [m] (defaults capped at 0.15 and 0.3 x
    the smallest node half; checked)."""
    half_min = min(_node_half(kind, depth, node_flat(kind, depth, lam, wheel_radius).length,
                              wheel_radius) for depth, lam in nodes)
    b0 = min(CENTRE_BAND, 0.15 * half_min) if centre_band is None else float(centre_band)
    b1 = min(EDGE_BAND, 0.3 * half_min) if edge_band is None else float(edge_band)
    if not (b0 >= 0 and b1 >= 0 and b0 + b1 < 0.6 * half_min):
        raise ValueError(f"centre_band + edge_band must be in [0, 0.6 x the smallest node "
                         f"half = {0.6 * half_min * 1e3:.3g} mm), got {b0!r}, {b1!r}")
    return b0, b1

"""The rail's Rayleigh-Timoshenko beam element (Friedman & Kosmatka 1993): its matrices, shape
functions and the in-element static correction, and the track's numbers checked; what the
finite track (:mod:`wfjax.model.fe`) and the infinite one (:mod:`wfjax.model.periodic`) are
built of."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..fields import concrete_positive_numbers
from ..params import SUPPORT_FIELDS, Track
from .sleepers import is_uniform, support_arrays

_RAIL_FIELDS = (
    "bending_stiffness", "shear_stiffness", "rail_mass", "rail_rotary_inertia",
    "sleeper_spacing",
)

def track_numbers(track: Track) -> dict[str, float | np.ndarray]:
    """Rail numbers (floats) and supports: a float per field when every sleeper has the same
    value (the uniform track: exactly today's numbers and cache keys), else the whole
    per-sleeper array [n_bays - 1] of every support field."""
    if not isinstance(track, Track):
        raise ValueError(f"track must be a wfjax.Track, got {type(track).__name__}")
    out: dict[str, float | np.ndarray] = dict(concrete_positive_numbers(track, _RAIL_FIELDS))
    arrays = support_arrays(track)
    uniform = is_uniform(track)
    for name in SUPPORT_FIELDS:
        if name == "ballast_gap" and not np.any(arrays[name]):
            continue  # no hanging sleeper: the numbers and cache keys of before
        out[name] = float(arrays[name][0]) if uniform else arrays[name]
    for name, low in (("n_bays", 4), ("elements_per_bay", 1)):
        value = getattr(track, name)
        if not isinstance(value, (int, np.integer)) or value < low:
            raise ValueError(f"Track.{name} must be an integer >= {low}, got {value!r}")
    return out

def element_matrices(bending_stiffness, shear_stiffness, rail_mass, rotary_inertia, length):
    """Friedman & Kosmatka (1993) Timoshenko element: stiffness and consistent mass [4x4].

    DOFs (w1, theta1, w2, theta2); units N/m, N, N m/rad and kg, kg m, kg m^2.
    Returns ``(K, M, phi)`` with ``M = M_t + M_r`` (translational + rotary inertia).
    """
    ei, L = bending_stiffness, length
    phi = 12.0 * ei / (shear_stiffness * L**2)
    k = ei / ((1 + phi) * L**3) * np.array([
        [12, 6 * L, -12, 6 * L],
        [6 * L, (4 + phi) * L**2, -6 * L, (2 - phi) * L**2],
        [-12, -6 * L, 12, -6 * L],
        [6 * L, (2 - phi) * L**2, -6 * L, (4 + phi) * L**2]])
    m11 = 70 * phi**2 + 147 * phi + 78
    m12 = (35 * phi**2 + 77 * phi + 44) * L / 4
    m13 = 35 * phi**2 + 63 * phi + 27
    m14 = -(35 * phi**2 + 63 * phi + 26) * L / 4
    m22 = (7 * phi**2 + 14 * phi + 8) * L**2 / 4
    m24 = -(7 * phi**2 + 14 * phi + 6) * L**2 / 4
    mt = rail_mass * L / (210 * (1 + phi) ** 2) * np.array([
        [m11, m12, m13, m14],
        [m12, m22, -m14, m24],
        [m13, -m14, m11, -m12],
        [m14, m24, -m12, m22]])
    r12 = -(15 * phi - 3) * L
    r22 = (10 * phi**2 + 5 * phi + 4) * L**2
    r24 = (5 * phi**2 - 5 * phi - 1) * L**2
    mr = rotary_inertia / (30 * (1 + phi) ** 2 * L) * np.array([
        [36, r12, -36, r12],
        [r12, r22, -r12, r24],
        [-36, -r12, 36, -r12],
        [r12, r24, -r12, r22]])
    return k, mt + mr, phi


def shape_functions(xi, phi, length):
    """Timoshenko displacement shape functions N1..N4 at xi = s / Le in [0, 1] (array-like).

    Returns a tuple of four arrays shaped like ``xi`` (N2, N4 in m/rad). Works with numpy and
    jax.numpy inputs.
    """
    xp = jnp if isinstance(xi, jax.Array) else np
    xi = xp.asarray(xi)
    d = 1.0 + phi
    n1 = (2 * xi**3 - 3 * xi**2 - phi * xi + 1 + phi) / d
    n2 = length * (xi**3 - (2 + phi / 2) * xi**2 + (1 + phi / 2) * xi) / d
    n3 = -(2 * xi**3 - 3 * xi**2 - phi * xi) / d
    n4 = length * (xi**3 - (1 - phi / 2) * xi**2 - (phi / 2) * xi) / d
    return n1, n2, n3, n4

NODE_SNAP = 1e-9  # a coordinate within this fraction of an element of a node lies on it


def fraction_in_element(s, element_length: float) -> np.ndarray:
    """Position of coordinates ``s`` [m] (measured from a node) within their elements, in
    [0, 1); 0 on a node (to :data:`NODE_SNAP`)."""
    xi = np.mod(np.asarray(s, dtype=float) / element_length, 1.0)
    return np.where(np.minimum(xi, 1 - xi) < NODE_SNAP, 0.0, xi)


def element_shapes(s, element_length: float, n_elements: int, phi: float):
    """(element index [n], shape functions [4, n]) of unit forces at coordinates ``s`` [m],
    [n], measured from the first node of ``n_elements`` elements; the element's dofs are
    2 e .. 2 e + 3 counting the first node's from 0. A coordinate on a node goes to the
    element it starts (the last node to the last element)."""
    s = np.asarray(s, dtype=float)
    e = np.clip(np.floor(s / element_length + NODE_SNAP).astype(int), 0, n_elements - 1)
    xi = (s - e * element_length) / element_length
    return e, np.stack(shape_functions(xi, phi, element_length), axis=0)

def element_interior_compliance(track: Track, xi) -> np.ndarray:
    """Static compliance [m/N] that the element's shape functions miss at a point load inside
    an element: the deflection under a unit load at fraction ``xi`` [any shape] of an element
    clamped at both its nodes (0 at the nodes).

    The Timoshenko element is exact for loads at its nodes only; a load inside it is spread
    to the nodes by the shape functions, which cannot follow the kink of the exact deflection
    under the load (mostly shear: about ``L / (4 kGA)`` at the middle, 8e-11 m/N for 8
    elements of 0.65 m). The exact deflection is the FE one plus this clamped-clamped
    part (superposition), computed exactly with a node at the load: two Timoshenko elements
    of lengths ``xi L`` and ``(1 - xi) L``.
    """
    p = track_numbers(track)
    ei, kga = float(p["bending_stiffness"]), float(p["shear_stiffness"])
    le = float(p["sleeper_spacing"]) / int(track.elements_per_bay)
    xi = np.asarray(xi, dtype=float)
    out = np.zeros(xi.shape)
    for i, x in np.ndenumerate(xi):
        if 1e-9 < x < 1 - 1e-9:
            ka = element_matrices(ei, kga, 1.0, 1.0, x * le)[0]
            kb = element_matrices(ei, kga, 1.0, 1.0, (1 - x) * le)[0]
            out[i] = np.linalg.inv(ka[2:, 2:] + kb[:2, :2])[0, 0]
    return out

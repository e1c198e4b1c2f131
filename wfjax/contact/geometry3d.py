"""The undeformed gap between a flat wheel and the rail head over a contact grid (the input of a
3D Kalker solve), the elliptic Hertz solution of the smooth wheel (Johnson 1985, Ch. 4), and the
grid that covers a flat's contact."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from ..model import geometry
from ..params import Flat, Material
from .influence import combined_modulus
from .kalker import MIN_ELEMENTS_ACROSS

_DEFAULT_MATERIAL = Material()


def gap_3d(flat: Flat, s, x, y, wheel_radius, rail_head_radius):
    """Undeformed gap [m] between a cylindrical wheel with a 3D flat and a straight rail.

    gap(x', y) = (R_W - sqrt(R_W^2 - x'^2)) + (R_R - sqrt(R_R^2 - y^2))
                 + flat_surface(flat, x' + s, y, R_R)

    The wheel is a cylinder (exact circle of radius R_W in x, no transverse curvature); the
    rail is straight in x with a transverse head radius R_R; the flat's transverse arcs use
    the same R_R (see :func:`wfjax.model.geometry.flat_surface`).

    Args:
        flat: the flat (its leaves are differentiable).
        s: wheel position [m] relative to the position where the flat centre is at the nominal
            contact point (s < 0 before the flat arrives). Scalar, differentiable.
        x: [nx] rail coordinates x' [m] relative to the nominal contact point (positive in the
            travel direction), element centres.
        y: [ny] transverse coordinates [m], element centres.
        wheel_radius: R_W [m]. rail_head_radius: R_R [m].

    Returns:
        [nx, ny] gap [m] (>= 0; 0 at the nominal contact point of a smooth wheel).
    """
    return _gap(flat, s, jnp.asarray(x), jnp.asarray(y), wheel_radius, rail_head_radius, jnp)


def _gap(flat: Flat, s, x, y, wheel_radius, rail_head_radius, xp):
    """:func:`gap_3d` with array module ``xp`` (np: a concrete flat's leaves, no compiling);
    ``s`` may be [n] (then [n, nx, ny])."""
    s = xp.asarray(s)[..., None]
    zx = wheel_radius - xp.sqrt(wheel_radius**2 - x**2)
    zy = rail_head_radius - xp.sqrt(rail_head_radius**2 - y**2)
    return zx[:, None] + zy[None, :] + geometry._surface(flat, x + s, y, rail_head_radius, xp)


def complete_elliptic(m: float) -> tuple[float, float]:
    """(K(m), E(m)): the complete elliptic integrals of the first and second kind, parameter
    m = k^2 in [0, 1), by the arithmetic-geometric mean (Abramowitz & Stegun 17.6): a few
    iterations to rounding, without importing ``scipy.special`` (0.1-0.4 s of a warm sweep,
    whose physics guards call :func:`elliptic_hertz`)."""
    a, b, c = 1.0, math.sqrt(1.0 - m), math.sqrt(m)
    total, power = 0.5 * c * c, 0.5  # sum of 2^(n-1) c_n^2
    for _ in range(60):  # quadratic convergence: c_n^2 below rounding in <= 8 steps here
        if abs(c) <= 1e-15 * a:
            break
        a, b, c = 0.5 * (a + b), math.sqrt(a * b), 0.5 * (a - b)
        power *= 2.0
        total += power * c * c
    k = math.pi / (2.0 * a)
    return k, k * (1.0 - total)


def elliptic_hertz(force, radius_x, radius_y, material: Material = _DEFAULT_MATERIAL):
    """Elliptic Hertz contact of two bodies with principal relative radii R_x, R_y (concrete).

    Relative curvatures A = 1/(2 R_x), B = 1/(2 R_y). Johnson (1985) Sec. 4.2: with semi-axes
    a (along the smaller curvature), b and e^2 = 1 - b^2/a^2,
    B/A = ((a/b)^2 E(e) - K(e)) / (K(e) - E(e)), a^3 = 3 F (K - E) / (2 pi E* e^2 A_min),
    delta = 3 F K(e) / (2 pi a E*), p0 = 3 F / (2 pi a b).

    Args:
        force: F [N]; radius_x, radius_y: relative radii of curvature [m] along x and y;
        material: both bodies.

    Returns:
        (semi_axis_x [m], semi_axis_y [m], approach [m], max_pressure [Pa]) as floats.
    """
    estar = float(combined_modulus(material))
    A, B = 1 / (2 * float(radius_x)), 1 / (2 * float(radius_y))
    lo, hi = min(A, B), max(A, B)
    F = float(force)
    ratio = hi / lo
    if abs(ratio - 1) < 1e-12:
        a = (3 * F / (8 * estar * lo)) ** (1 / 3)
        return a, a, a * a * 2 * lo, 3 * F / (2 * math.pi * a * a)

    def f(m):  # m = e^2
        k, e = complete_elliptic(m)
        return (e / (1 - m) - k) / (k - e) - ratio

    # B/A grows monotonically with m: bisection (importing scipy.optimize for brentq took
    # 0.1-0.9 s of a cold sweep's table thread)
    lo_m, hi_m = 1e-12, 1 - 1e-15
    while hi_m - lo_m > 1e-15 * (1 + hi_m):
        mid = 0.5 * (lo_m + hi_m)
        lo_m, hi_m = (mid, hi_m) if f(mid) < 0 else (lo_m, mid)
    m = 0.5 * (lo_m + hi_m)
    k, e = complete_elliptic(m)
    a = (3 * F * (k - e) / (2 * math.pi * estar * m * lo)) ** (1 / 3)
    b = a * math.sqrt(1 - m)
    delta = 3 * F * k / (2 * math.pi * a * estar)
    p0 = 3 * F / (2 * math.pi * a * b)
    ax, ay = (a, b) if A <= B else (b, a)
    return ax, ay, delta, p0


def contact_grid(flat: Flat, wheel_radius: float, rail_head_radius: float,
                 material: Material = _DEFAULT_MATERIAL, max_compression: float | None = None,
                 max_force: float = 600e3, element_size: float = 1e-3, margin: int = 2):
    """Element centres (x [nx], y [ny]) [m] of a grid that contains every contact up to a load.

    The contact lies inside the rigid overlap {gap < delta} (displacements are >= 0), and
    gap >= x'^2/(2 R_W) (approximately) and >= y^2/(2 R_R), while min(gap) <= depth. So a
    compression c = delta - min(gap) keeps the contact within |x'| <= sqrt(2 R_W (d + c)) and
    |y| <= sqrt(2 R_R (d + c)) for every flat position s. The grid is symmetric with an
    element centred on the nominal contact point (odd counts) plus ``margin`` elements.

    Args:
        flat: the flat (concrete depth).
        wheel_radius, rail_head_radius: R_W, R_R [m].
        material: for the Hertz estimate.
        max_compression: largest c [m]; default 1.5 x the Hertz approach at ``max_force``.
        max_force: force [N] used for the default compression and the resolution check.
        element_size: square element side [m].
        margin: extra elements on each side.

    Returns:
        (x, y) numpy arrays of element centres [m].

    Raises:
        ValueError: non-positive element size, or fewer than 6 elements across the smooth
            Hertz contact at ``max_force`` / 4 (too coarse to resolve the contact).
    """
    h = float(element_size)
    if not math.isfinite(h) or h <= 0:
        raise ValueError(f"element_size must be > 0 m, got {element_size!r}")
    ax, ay, dH, _ = elliptic_hertz(max_force, wheel_radius, rail_head_radius, material)
    ax8, ay8, _, _ = elliptic_hertz(max_force / 4, wheel_radius, rail_head_radius, material)
    if 2 * min(ax8, ay8) / h < MIN_ELEMENTS_ACROSS:
        raise ValueError(
            f"element_size {h * 1e3:.3g} mm too coarse: the Hertz contact at "
            f"{max_force / 4e3:.3g} kN is only {2 * min(ax8, ay8) * 1e3:.3g} mm wide; need "
            f"element_size <= {2 * min(ax8, ay8) / MIN_ELEMENTS_ACROSS * 1e3:.3g} mm"
        )
    c = 1.5 * dH if max_compression is None else float(max_compression)
    d = float(np.max(np.asarray(flat.depth))) if flat.kind != "none" else 0.0
    half_x = math.sqrt(2 * float(wheel_radius) * (d + c))
    half_y = math.sqrt(2 * float(rail_head_radius) * (d + c))
    nx_half = math.ceil(half_x / h) + margin
    ny_half = math.ceil(half_y / h) + margin
    x = np.arange(-nx_half, nx_half + 1) * h
    y = np.arange(-ny_half, ny_half + 1) * h
    return x, y

"""Linear interpolation on a uniform grid: an O(1) gather instead of ``jnp.interp``'s search.

The time loop interpolates tabulated curves (wheel-centre trajectory, residual compliance)
at every step and, for the trajectory, in every Newton iteration; a binary search over
thousands of points per evaluation costs more than the rest of the Hertz step.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def interp_uniform(x, x_first, x_last, y, outside=None) -> jax.Array:
    """Piecewise-linear y(x) sampled at ``len(y)`` evenly spaced points x_first ... x_last.

    Args:
        x: query points, any shape (units of x_first).
        x_first, x_last: first and last grid point (x_last > x_first).
        y: float [n >= 2] values at the grid points.
        outside: value returned outside [x_first, x_last]; ``None`` clamps to the end values
            (as ``jnp.interp`` without ``left``/``right``).

    Returns:
        float array of ``x``'s shape. Differentiable in x (slope of the segment) and y.
    """
    n = y.shape[0]
    u = (x - x_first) / (x_last - x_first) * (n - 1)
    u_clamped = jnp.clip(u, 0.0, n - 1.0)
    i = jnp.clip(jnp.floor(u_clamped).astype(jnp.int32), 0, n - 2)
    w = u_clamped - i
    value = (1.0 - w) * y[i] + w * y[i + 1]
    if outside is None:
        return value
    return jnp.where((u < 0.0) | (u > n - 1.0), outside, value)

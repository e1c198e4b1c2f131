"""Parametrisations of a flat's geometry by an unconstrained vector theta (constraints kept
by reparametrisation; see :mod:`wfjax.fit`)."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from ..params import Flat, new_flat_length

__all__ = ["D_REF", "NewFlatParam", "RoundedFlatParam", "ProfileParam", "parametrisation_for"]

D_REF = 1e-3  # m: depth scale of the parametrisations



# -- parametrisations -----------------------------------------------------------------------
def _softplus_inv(y):
    y = np.asarray(y, dtype=float)
    return y + np.log(-np.expm1(-y))


@dataclasses.dataclass(frozen=True)
class NewFlatParam:
    """New flat: theta = [log(depth / 1 mm)]; physical parameters (depth [m],).

    Attributes:
        wheel_radius: R_W [m]. extent_bound: static bound of the flat's half extent [m].
    """

    wheel_radius: float = 0.45
    extent_bound: float = 0.06
    names: tuple = ("depth",)

    def to_flat(self, theta) -> Flat:
        depth = D_REF * jnp.exp(theta[0])
        return Flat("new", depth, new_flat_length(depth, self.wheel_radius),
                    wheel_radius=self.wheel_radius, extent_bound=self.extent_bound)

    def physical(self, theta):
        """[1] depth [m]."""
        return D_REF * jnp.exp(theta[:1])

    def from_flat(self, flat: Flat) -> np.ndarray:
        return np.array([math.log(float(flat.depth) / D_REF)])

    def penalty(self, theta):
        return jnp.zeros(())


@dataclasses.dataclass(frozen=True)
class RoundedFlatParam:
    """Rounded flat: theta = [log(d / 1 mm), softplus^-1(l / l0(d) - pi/2)].

    Physical parameters (depth [m], length [m]); length >= pi/2 l0(depth) for every theta.
    """

    wheel_radius: float = 0.45
    extent_bound: float = 0.1
    names: tuple = ("depth", "length")

    def physical(self, theta):
        """[2] (depth [m], length [m])."""
        depth = D_REF * jnp.exp(theta[0])
        l0 = new_flat_length(depth, self.wheel_radius)
        return jnp.stack([depth, l0 * (jnp.pi / 2 + jax.nn.softplus(theta[1]))])

    def to_flat(self, theta) -> Flat:
        depth, length = self.physical(theta)
        return Flat("rounded", depth, length, wheel_radius=self.wheel_radius,
                    extent_bound=self.extent_bound)

    def from_flat(self, flat: Flat) -> np.ndarray:
        depth, length = float(flat.depth), float(flat.length)
        ratio = length / float(new_flat_length(depth, self.wheel_radius)) - math.pi / 2
        return np.array([math.log(depth / D_REF), float(_softplus_inv(max(ratio, 1e-6)))])

    def penalty(self, theta):
        return jnp.zeros(())


@dataclasses.dataclass(frozen=True)
class ProfileParam:
    """Measured-like flat: K non-negative raised-cosine bumps on a fixed support.

    z(x) = sum_k a_k b_k(x), a_k = 1 mm * softplus(theta_k) >= 0, with
    b_k(x) = (1 + cos(pi (x - x_k) / h)) / 2 for |x - x_k| < h, h = 2 dx, centres x_k evenly
    spaced (dx) from -L/2 + h to L/2 - h, so z is C1, >= 0 and zero outside [-L/2, L/2].
    Physical parameters: the amplitudes a_k [m]. Penalty (added to the loss):
    ``smoothing * sum_k (a_{k-1} - 2 a_k + a_{k+1})^2 / (1 mm)^2`` against noise.

    Attributes:
        half_length: L/2 [m] (static support). n_basis: K. n_grid: samples of the profile.
        smoothing: weight of the penalty (the data term is the mean squared relative residual).
        wheel_radius: R_W [m].
    """

    half_length: float = 0.06
    n_basis: int = 8
    n_grid: int = 121
    smoothing: float = 1e-3
    wheel_radius: float = 0.45

    @property
    def names(self) -> tuple:
        return tuple(f"amplitude_{k}" for k in range(self.n_basis))

    @property
    def extent_bound(self) -> float:
        return float(self.half_length)

    def _basis(self) -> np.ndarray:
        """[n_grid, K] basis values on the profile grid."""
        dx = 2 * self.half_length / (self.n_basis + 3)
        h = 2 * dx
        centres = -self.half_length + h + dx * np.arange(self.n_basis)
        x = self.grid()[:, None]
        u = np.clip((x - centres) / h, -1.0, 1.0)
        return 0.5 * (1 + np.cos(np.pi * u))

    def grid(self) -> np.ndarray:
        """[n_grid] circumferential positions of the profile samples [m]."""
        return np.linspace(-self.half_length, self.half_length, self.n_grid)

    def physical(self, theta):
        """[K] bump amplitudes [m]."""
        return D_REF * jax.nn.softplus(theta)

    def to_flat(self, theta) -> Flat:
        z = jnp.asarray(self._basis()) @ self.physical(theta)
        return Flat("profile", jnp.max(z), 2 * self.half_length, wheel_radius=self.wheel_radius,
                    profile_x=jnp.asarray(self.grid()), profile_z=z,
                    extent_bound=self.extent_bound)

    def from_flat(self, flat: Flat) -> np.ndarray:
        from ..model.geometry import profile_deviation

        z = np.asarray(profile_deviation(flat, self.grid()))
        amp, *_ = np.linalg.lstsq(self._basis(), z, rcond=None)
        return _softplus_inv(np.maximum(amp / D_REF, 1e-3))

    def penalty(self, theta):
        a = jax.nn.softplus(theta)
        return self.smoothing * jnp.sum((a[:-2] - 2 * a[1:-1] + a[2:]) ** 2)


def parametrisation_for(flat: Flat, extent_bound: float | None = None, **options):
    """Default parametrisation for the kind of ``flat`` (new, rounded or profile).

    ``extent_bound`` [m] bounds the half extent the flat may reach during the fit (sizes the
    numerical windows); default 1.5 x the initial half extent (the profile support for
    ``"profile"``, whose support is fixed).
    """
    radius = float(flat.wheel_radius)
    if flat.kind == "profile":
        half = float(max(abs(np.asarray(flat.profile_x)[[0, -1]])))
        return ProfileParam(half_length=half, wheel_radius=radius, **options)
    half = float(flat.length) / 2
    bound = 1.5 * half if extent_bound is None else float(extent_bound)
    if flat.kind == "new":
        return NewFlatParam(wheel_radius=radius, extent_bound=bound)
    if flat.kind == "rounded":
        return RoundedFlatParam(wheel_radius=radius, extent_bound=bound)
    raise ValueError(f"cannot fit a flat of kind {flat.kind!r}; use new, rounded or profile")

"""Modal data of the wheels and the track the time loop reads, and the rail terms at the
contacts: mode shapes, modal loads, the rail's compliance within a step between wheels.

One wheel is a vehicle of one: every array has a leading wheel axis.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._xla import to_device
from ..model import supports as supports_mod
from ..model import track as track_mod
from ..model import vehicle as vehicle_mod
from ..params import SimConfig, Track, Wheel


class Structure(NamedTuple):
    """Modal data of the wheels and the track used by the time loop (arrays; a pytree).

    (:func:`structure`) ``wheel_poles``, ``wheel_residues``, ``axle_residues`` [n_wheels, n_w]
    and ``preload`` [n_wheels] N, one row per wheel (one wheel is a vehicle of one), and
    ``offsets`` [n_wheels] (rail coordinate of every wheel relative to the reference wheel
    [m]), ``delays`` [n_wheels] (the flats' delays [m], :class:`wfjax.model.vehicle.Vehicle`) and
    ``residual_pairs`` [n_res, n_wheels, n_wheels] (static compliance of the truncated track
    modes between the wheels across one bay, or along the whole rail when the supports vary:
    :func:`wfjax.model.vehicle.residual_pairs`; None for one wheel, whose own residual is the modal
    model's residual table). ``supports``: the track's one-sided (hanging)
    sleepers, :func:`wfjax.model.supports.one_sided_spec`, or None. ``revolutions`` [n_wheels]
    m: every wheel's circumference 2 pi R when its flat strikes once per revolution
    (:attr:`wfjax.model.vehicle.Vehicle.repeat_flats`), or None (one strike per run).
    """

    track: Any  # track.ModalModel
    wheel_poles: Any  # complex [n_w] rad/s
    wheel_residues: Any  # complex [n_w] m/(N s): h_W(t) = Re sum residues exp(poles t)
    preload: Any  # N
    axle_residues: Any = None  # complex [n_w] m/(N s): the wheelset mass's (axle box's) h
    offsets: Any = None
    delays: Any = None
    residual_pairs: Any = None
    supports: Any = None  # supports.OneSidedSupports of hanging sleepers, or None
    revolutions: Any = None  # [n_wheels] m, or None


def structure(vehicle, wheels: list[Wheel], track: Track, config: SimConfig,
              cache_dir=None) -> Structure:
    """:class:`Structure` of a :class:`wfjax.model.vehicle.Vehicle` (one wheel:
    ``Vehicle.single()``) with wheel models ``wheels`` ([n] :class:`Wheel`), placed on the
    track by :func:`wfjax.model.vehicle.placement`; the track's modal model is cached on disk in
    ``cache_dir``; ``config``'s auto mode cut-off is the force's unless resolved
    (:meth:`SimConfig.resolved`)."""
    model = track_mod.modal_model(track, max_frequency=config.resolved().track_max_frequency,
                                  cache_dir=cache_dir)
    ws = vehicle_mod.wheel_set(wheels)
    offsets = vehicle.offsets()
    pairs = None  # one wheel: its own residual compliance is the model's residual table
    if vehicle.n_wheels > 1:
        pairs = to_device(vehicle_mod.residual_pairs(
            track, model, offsets, vehicle_mod.placement(vehicle, float(track.sleeper_spacing))))
    revolutions = None
    if vehicle.repeat_flats:
        revolutions = to_device(2 * np.pi * np.array([float(w.radius) for w in wheels]))
    return Structure(model, ws.poles, ws.residues, ws.preload, ws.axle_residues,
                     to_device(np.asarray(offsets, float)),
                     to_device(np.asarray(vehicle.delays(), float)), pairs,
                     _one_sided(track, model, offsets), revolutions)


def _one_sided(track: Track, model, offsets=(0.0,)):
    spec = supports_mod.one_sided_spec(track, model, offsets)
    return None if spec is None else jax.tree_util.tree_map(jnp.asarray, spec)


def node_major_shapes(model):
    """Mode shapes as [n_nodes, 2, n_modes]: each step gathers two contiguous rows."""
    return jnp.transpose(model.shapes, (1, 2, 0))


def rail_terms(model, node_major, x):
    """(phi_r(x) [n_modes], residual compliance [m/N]) at rail position ``x`` [m].

    Same interpolation as :func:`wfjax.model.track.mode_shapes_at` (tested equal), on node-major
    shapes so the per-step gather reads contiguous memory.
    """
    phi = track_mod.interpolate_nodal(model, node_major, x)
    return phi, track_mod.residual_compliance_at(model, x)


def residual_matrix(struct: Structure, model, x_ref):
    """[n, n] static compliance of the truncated modes between the wheels [m/N] with the
    reference wheel at ``x_ref`` [m] (one wheel: the track's own residual there)."""
    if struct.residual_pairs is None:
        return track_mod.residual_compliance_at(model, x_ref)[None, None]
    own = track_mod.residual_compliance_at(model, x_ref + struct.offsets)
    return track_mod.read_residual_table(model, struct.residual_pairs, x_ref) + jnp.diag(own)


def modal_loads(f, phi):
    """sum_i f_i phi_i(x_i): modal loads [n_modes] of forces f [n] at shapes phi [n, n_modes]."""
    return sum(f[i] * phi[i] for i in range(f.shape[0]))


def rail_reads(phi, w_r, an_r, q_hat):
    """(xi_free [n] m, c [n] m/N): the rail at every wheel from the propagated modal state
    ``q_hat`` [n_modes], Re sum_r w_r phi_ir q_r, and every wheel's own rail compliance
    within the step, Re sum_r w_r an_r phi_ir^2, for shapes ``phi`` [n, n_modes]."""
    xi = jnp.real(jnp.sum(phi * (w_r * q_hat), axis=-1))
    return xi, jnp.real(jnp.sum(w_r * an_r * phi * phi, axis=-1))


def shapes_fn(model):
    """x [n] m -> the mode shapes there, [n, n_modes] complex: the time loop's node-major
    interpolation (each wheel gathers two contiguous rows)."""
    node_major = node_major_shapes(model)
    return lambda x: jax.vmap(lambda xi: track_mod.interpolate_nodal(model, node_major, xi))(x)


def cross_table_origin(model, impact_position):
    """x_bay [m] of :func:`cross_table` for a run: the impact's bay on a uniform track (the
    table is read periodically), 0 when the supports vary (the table runs along the rail)."""
    return jnp.where(track_mod.residual_table_is_periodic(model),
                     impact_position - jnp.mod(impact_position, model.sleeper_spacing), 0.0)


def cross_table(model, shapes_at, offsets, weight, x_bay):
    """[n_res, n, n] the rail's compliance within a step between different wheels,
    Re sum_r weight_r phi_r(x + o_i) phi_r(x + o_j) (zero diagonal), for the reference wheel
    at x = x_bay + model.residual_x: across one bay on a uniform track, along the whole rail
    (``x_bay`` = 0) when the supports vary (read by :func:`wfjax.model.track.read_residual_table`).

    These cross terms are about 1e-3 of a wheel's own step compliance (the rail's response
    within one step hardly reaches the next wheel), but summing them over the modes at every
    step would cost n (n - 1) / 2 passes over the modes: tabulated once per run across the
    bay, like the residual compliance, and interpolated, they cost what 33 steps cost (along
    the whole rail when the supports vary, 2241 points: a bogie's ``simulate`` there took
    1.26x the uniform track's, tables and all).
    """
    n = offsets.shape[0]
    upper = np.triu_indices(n, 1)

    def at(x):
        phi = shapes_at(x + offsets)
        values = jnp.real(jnp.sum(weight * phi[upper[0]] * phi[upper[1]], axis=-1))
        table = jnp.zeros((n, n), values.dtype).at[upper].set(values)
        return table + table.T

    return jax.lax.map(at, x_bay + model.residual_x)


def rail_compliance_fn(ls):
    """For a :class:`wfjax.loop.setup.LoopSetup` ``ls``: (x_ref m, c_own [n] m/N) -> the
    rail's compliance within a step between the wheels, [n, n] m/N, with the reference wheel
    at ``x_ref``: the wheels' own kept-mode compliance ``c_own`` (:func:`rail_reads`) on the
    diagonal, the truncated modes' static compliance and, for several wheels, the kept
    modes' cross terms (:func:`cross_table`, built once here)."""
    struct, model = ls.struct, ls.struct.track
    cross = None
    if len(ls.laws) > 1:
        cross = cross_table(model, shapes_fn(model), ls.offsets, model.weights * ls.an_r,
                             cross_table_origin(model, ls.impact_position))

    def rail_compliance(x_ref, c_own):
        c_rail = jnp.diag(c_own) + residual_matrix(struct, model, x_ref)
        if cross is not None:
            c_rail = c_rail + track_mod.read_residual_table(model, cross, x_ref)
        return c_rail

    return rail_compliance

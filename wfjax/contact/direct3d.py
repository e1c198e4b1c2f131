"""Reference mode of the 3D contact: a Kalker solve at every Newton iterate of every step.

Used with ``SimConfig(contact_mode_3d="direct")`` to check the tabulated F3D(delta, s) of
:mod:`wfjax.contact.tables` and the parametric family of :mod:`wfjax.contact.family`. While
the flat is within reach of the contact grid, every step solves
r(delta) = delta - delta_free + c F(delta) by the bracketed Newton iteration of
:func:`wfjax.contact.newton.bracketed_newton`, each evaluation being an approach-controlled
Kalker solve warm-started from the previous pressure field (the law's state); its slope is the
solver's contact stiffness. Outside that reach the flat cannot touch the grid and the contact
is the smooth wheel's, which the table holds exactly (its outer columns are direct solves on
the same grid), so the table is used there.

Each solve runs on the window of the table's build plan (:func:`wfjax.contact.tables.
window_plan`) for the nearest column and the next tabulated compression at or above the
iterate's: the window contains the rigid overlap, so the solve is the whole-grid problem. When
the overlap reaches the window's edge (a compression beyond the table's range) the solve falls
back to the whole grid.

Not differentiated (a reference); forward results only.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._xla import to_device
from ..fields import pytree
from ..params import Flat, Material, SimConfig, Track, Wheel
from . import interpolation, table_spec, windows
from .newton import bracketed_newton
from .table_law import TableLaw, cached_table_3d

__all__ = ["Direct3DLaw", "prepare_direct"]

KALKER_TOL = 1e-10  # relative CG tolerance of the per-step solves
DIRECT_WINDOW_SIZES = 2  # static window sizes of the per-step solves (plus the whole grid)


@pytree(static=("layout", "window_sizes"))
class Direct3DLaw(TableLaw):
    """A Kalker solve per Newton iterate near the flat; the exact table elsewhere.

    Attributes:
        table: the flat's :class:`wfjax.contact.interpolation.ContactTable` (far field, start).
        flat: the flat (concrete: it fixes the grid). material: wheel and rail material.
        window_index, window_x0, window_y0: [n_s, n_t] the window (size index, first grid
            indices) of every column and tabulated compression (node 0: node 1's).
        layout (static): the table's :class:`wfjax.contact.table_spec.TableSpec` (grid, reach).
        window_sizes (static): the windows' sizes (wx, wy) [elements].
    """

    table: Any
    flat: Flat
    material: Material
    window_index: Any
    window_x0: Any
    window_y0: Any
    layout: table_spec.TableSpec
    window_sizes: tuple

    def init_state(self):
        return jnp.zeros((self.layout.nx, self.layout.ny))

    def on_whole_grid(self) -> Direct3DLaw:
        """The same law with every solve on the table's whole grid (the reference of the
        windows: tests and benchmarks)."""
        zeros = {k: jnp.zeros_like(getattr(self, k))
                 for k in ("window_index", "window_x0", "window_y0")}
        return dataclasses.replace(self, window_sizes=((self.layout.nx, self.layout.ny),),
                                   **zeros)

    def rough_nodes(self):
        """[nx] element centres x' [m] of the contact grid: the roughness is read there."""
        return jnp.asarray(self.layout.x)

    def _evaluate(self, s, delta, pressure, rough_x=None, rough_eq=0.0):
        """Force [N], stiffness [N/m] and the whole-grid pressure of one solve at (delta, s),
        with ``rough_x`` [nx] [m] (or None) taken off the gap along x'."""
        layout = self.layout
        n_s, n_t = self.window_index.shape
        phi = interpolation.column_coordinate(s, jnp.asarray(layout.stretch))
        j = jnp.clip(jnp.round((phi + layout.phi_max) / (2 * layout.phi_max) * (n_s - 1)), 0,
                     n_s - 1).astype(jnp.int32)
        c = delta + rough_eq - interpolation.table_onset(self.table, s)
        k = jnp.clip(jnp.ceil(jnp.sqrt(jnp.maximum(c, 0.0) / layout.c_max) * (n_t - 1)), 1,
                     n_t - 1).astype(jnp.int32)

        def solve_on(nx, ny, i0, j0):
            res, gap, full, _ = windows.window_solve(layout, self.flat, self.material, s, delta,
                                                    (nx, ny), (i0, j0), pressure, KALKER_TOL,
                                                    rough_x=rough_x)
            # The window holds the contact unless the overlap {gap < delta} reaches its edge.
            edge = jnp.minimum(jnp.minimum(gap[0].min(), gap[-1].min()),
                               jnp.minimum(gap[:, 0].min(), gap[:, -1].min()))
            return res.force, res.stiffness, full, (edge > delta) | (nx == layout.nx) & (
                ny == layout.ny)

        branches = [lambda i0, j0, size=size: solve_on(*size, i0, j0)
                    for size in self.window_sizes]
        force, stiff, full, inside = jax.lax.switch(
            self.window_index[j, k], branches, self.window_x0[j, k], self.window_y0[j, k])

        def whole_grid(_):
            return solve_on(layout.nx, layout.ny, 0, 0)[:3]

        return jax.lax.cond(inside, lambda _: (force, stiff, full), whole_grid, None)

    def step(self, delta_free, compliance, s, state, max_iter: int = 30, roughness=None):
        layout = self.layout
        rough_x, rough_eq = (None, 0.0) if roughness is None else roughness

        def near(delta_free, compliance, s, pressure):
            def evaluate(delta, p):
                return self._evaluate(s, delta, p, rough_x, rough_eq)

            delta, r, pressure = bracketed_newton(evaluate, delta_free, compliance, pressure,
                                                  max_iter, 1e-14)
            f, _, pressure = evaluate(delta, pressure)
            return delta, f, r, pressure

        def far(delta_free, compliance, s, pressure):
            delta, f, r, _ = TableLaw.step(self, delta_free + rough_eq, compliance, s, None,
                                           max_iter)
            return delta - rough_eq, f, r, jnp.zeros_like(pressure)

        return jax.lax.cond(jnp.abs(s) < layout.s_max, near, far, delta_free, compliance, s,
                            state)


def prepare_direct(flat: Flat, wheel: Wheel, track: Track, material: Material,
                   config: SimConfig, cache_dir=None) -> Direct3DLaw:
    """The direct 3D law of a concrete ``flat`` (its table through the on-disk cache)."""
    radius, rail_radius = float(wheel.radius), float(track.rail_head_radius)
    layout = table_spec.table_spec(flat, radius, rail_radius, material,
                               element_size=config.contact_element)
    table = cached_table_3d(flat, radius, rail_radius, material, config.contact_element,
                            cache_dir)
    # Two window sizes: every size is one more compiled Kalker solver inside the Newton loop
    # (about 3-4 s of compilation each here), and a direct run is usually a single run.
    plan = windows.window_plan(layout, flat, layout.s, max_sizes=DIRECT_WINDOW_SIZES)

    def per_node(a):  # [n_s, n_t - 1] -> [n_t]: node 0 (F = 0) takes node 1's window
        return to_device(np.concatenate([a[:, :1], a], axis=1))

    return Direct3DLaw(table, flat, material, per_node(plan.size_index), per_node(plan.x0),
                       per_node(plan.y0), layout, plan.sizes)

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

Not differentiated (a reference); forward results only.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from ..params import Flat, Material, SimConfig, Track, Wheel, _pytree
from . import kalker, tables
from .laws import TableLaw, cached_table_3d
from .newton import bracketed_newton

__all__ = ["Direct3DLaw", "prepare_direct"]

KALKER_TOL = 1e-10  # relative CG tolerance of the per-step solves


@_pytree(static=("layout",))
class Direct3DLaw(TableLaw):
    """A Kalker solve per Newton iterate near the flat; the exact table elsewhere.

    Attributes:
        table: the flat's :class:`wfjax.contact.tables.ContactTable` (far field, start).
        flat: the flat (concrete: it fixes the grid). material: wheel and rail material.
        layout (static): the table's :class:`wfjax.contact.tables.TableSpec` (grid, reach).
    """

    table: Any
    flat: Flat
    material: Material
    layout: tables.TableSpec

    def init_state(self):
        return jnp.zeros((self.layout.nx, self.layout.ny))

    def step(self, delta_free, compliance, s, state, max_iter: int = 30):
        layout = self.layout
        x, y = jnp.asarray(layout.x), jnp.asarray(layout.y)
        h = layout.element_size
        cfg = kalker._Config(layout.nx, layout.ny, h, h, "fft", KALKER_TOL, 1000)

        def near(delta_free, compliance, s, pressure):
            gap = kalker.gap_3d(self.flat, s, x, y, layout.wheel_radius,
                                layout.rail_head_radius)

            def evaluate(delta, p):
                res, _ = kalker._solve_impl(cfg, gap, self.material, delta, None, p, 50, True,
                                            False)
                return res.force, res.stiffness, res.pressure

            delta, r, pressure = bracketed_newton(evaluate, delta_free, compliance, pressure,
                                                  max_iter, 1e-14)
            f, _, pressure = evaluate(delta, pressure)
            return delta, f, r, pressure

        def far(delta_free, compliance, s, pressure):
            delta, f, r, _ = TableLaw.step(self, delta_free, compliance, s, None, max_iter)
            return delta, f, r, jnp.zeros_like(pressure)

        return jax.lax.cond(jnp.abs(s) < layout.s_max, near, far, delta_free, compliance, s,
                            state)


def prepare_direct(flat: Flat, wheel: Wheel, track: Track, material: Material,
                   config: SimConfig, cache_dir=None) -> Direct3DLaw:
    """The direct 3D law of a concrete ``flat`` (its table through the on-disk cache)."""
    radius, rail_radius = float(wheel.radius), float(track.rail_head_radius)
    layout = tables.table_spec(flat, radius, rail_radius, material,
                               element_size=config.contact_element)
    table = cached_table_3d(flat, radius, rail_radius, material, config.contact_element,
                            cache_dir)
    return Direct3DLaw(table, flat, material, layout)

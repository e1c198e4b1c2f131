"""Reference mode of the 3D contact: a Kalker solve at every Newton iterate of every step.

Used by :func:`wfjax.simulate` with ``SimConfig(contact_mode_3d="direct")`` to check the
tabulated F3D(delta, s) of :mod:`wfjax.contact.tables`. While the flat is within reach of the
contact grid, every step solves r(delta) = delta - delta_free + c F(delta) by the bracketed
Newton iteration of :func:`wfjax.interaction.bracketed_newton`, each evaluation being an
approach-controlled Kalker solve warm-started from the previous pressure field; its slope is
the solver's contact stiffness. Outside that reach the flat cannot touch the grid and the
contact is the smooth wheel's, which the table holds exactly (its outer columns are direct
solves on the same grid), so the table is used there.

Not differentiated (a reference); forward results only.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp

from .contact import kalker, tables
from .interaction import (
    Structure,
    bracketed_newton,
    cached_table_3d,
    solve_contact_step,
    time_loop,
)
from .params import Flat, Material, SimConfig, Track, Wheel

__all__ = ["run_direct_3d"]

KALKER_TOL = 1e-10  # relative CG tolerance of the per-step solves


@partial(jax.jit, static_argnames=("layout", "n_steps", "max_iter"))
def _run(layout: tables.TableSpec, flat: Flat, table, material: Material, struct: Structure,
         speed, dt, x_start, impact_position, n_steps: int, max_iter: int):
    x, y = jnp.asarray(layout.x), jnp.asarray(layout.y)
    h = layout.element_size
    cfg = kalker._Config(layout.nx, layout.ny, h, h, "fft", KALKER_TOL, 1000)
    reach = layout.s_max

    def table_law(delta, s):
        return tables.table_force(table, delta, s)

    def near_step(delta_free, compliance, s, pressure):
        gap = kalker.gap_3d(flat, s, x, y, layout.wheel_radius, layout.rail_head_radius)

        def evaluate(delta, p):
            res, _ = kalker._solve_impl(cfg, gap, material, delta, None, p, 50, True, False)
            return res.force, res.stiffness, res.pressure

        delta, r, pressure = bracketed_newton(evaluate, delta_free, compliance, pressure,
                                              max_iter, 1e-14)
        f, _, pressure = evaluate(delta, pressure)
        return delta, f, r, pressure

    def far_step(delta_free, compliance, s, pressure):
        delta, f, r = solve_contact_step(lambda d: table_law(d, s), delta_free, compliance,
                                         max_iter)
        return delta, f, r, jnp.zeros_like(pressure)

    def contact_step(delta_free, compliance, s, pressure):
        return jax.lax.cond(jnp.abs(s) < reach, near_step, far_step, delta_free, compliance, s,
                            pressure)

    p0 = jnp.zeros((layout.nx, layout.ny))
    return time_loop(contact_step, table_law, p0, struct, speed, dt, x_start, impact_position,
                     n_steps)


def run_direct_3d(flat: Flat, struct: Structure, speed: float, dt: float, x_start: float,
                  impact_position: float, n_steps: int, wheel: Wheel, track: Track,
                  material: Material, config: SimConfig):
    """Histories of a simulation with a direct Kalker solve per step (see module docstring).

    Args:
        flat: the flat. struct: modal wheel and track. speed [m/s], dt [s], x_start [m],
        impact_position [m], n_steps: as :func:`wfjax.interaction.time_loop`.
        wheel, track, material, config: parameters (R_W, R_R, E, nu, contact element size).

    Returns:
        dict of [n_steps] arrays (t, x, s, force, approach, wheel_disp, rail_disp, residual).
    """
    layout = tables.table_spec(flat, float(wheel.radius), float(track.rail_head_radius),
                               material, element_size=config.contact_element)
    table = cached_table_3d(flat, float(wheel.radius), float(track.rail_head_radius), material,
                            config.contact_element)
    return _run(layout, flat, table, material, struct, speed, dt, x_start, impact_position,
                n_steps, config.newton_iterations)

"""The protocol every contact law implements: what the time loop needs from a contact model.

A law is a pytree built once by a prepare function (:mod:`wfjax.contact.registry`, the
concrete work: node sets, trajectory grids, 3D tables) and evaluated inside the compiled time
step through :class:`ContactLaw`:

* ``law.point(s)``: the work that depends only on the flat position s [m] (a gap at the
  bedding nodes, an interpolated 3D table column, the trajectory's drop), done once per step;
* ``law.point_force(point, delta)``: the force F [N] at approach delta [m], evaluated at every
  Newton iterate of the step;
* ``law.force(delta, s)``: both at once (static equilibrium, plots, tests);
* ``law.init_state()`` and ``law.step(delta_free, compliance, s, state, max_iter)``: the
  step's scalar contact equation (:mod:`wfjax.contact.newton`); only the per-step direct 3D
  solve, which warm-starts Kalker's solver from the previous pressures, overrides them.

The law's class and its static fields (grid shapes) select the compiled program; the time
loop never sees a model's name.
"""

from __future__ import annotations

import jax

from .newton import solve_contact_step

__all__ = ["ContactLaw"]


class ContactLaw:
    """The protocol every contact law implements (see the module docstring)."""

    def point(self, s):
        """The s-dependent part of the law at flat position ``s`` [m] (a pytree)."""
        raise NotImplementedError

    def point_force(self, point, delta):
        """Contact force F [N] at approach ``delta`` [m] for a :meth:`point` result."""
        raise NotImplementedError

    def force(self, delta, s):
        """Contact force F [N] at approach ``delta`` [m] and flat position ``s`` [m]."""
        return self.point_force(self.point(s), delta)

    def init_state(self):
        """Initial per-step solver state carried by the time loop (``None``: stateless)."""
        return None

    def rough_nodes(self):
        """[n] offsets x' [m] from the nominal contact point (travel direction) where the law
        reads rail and wheel roughness element by element, or None: a point-contact law,
        to whose approach the time loop adds the contact-filtered roughness instead."""
        return None

    def rough_point(self, s, roughness):
        """:meth:`point` with ``roughness`` [n] [m] (positive = surface raised) at
        :meth:`rough_nodes` taken off the gap (laws with :meth:`rough_nodes` only)."""
        raise NotImplementedError

    def step(self, delta_free, compliance, s, state, max_iter: int = 30, roughness=None):
        """Solve the step's contact equation delta = delta_free - compliance F(delta, s).

        Args:
            delta_free: approach if F were zero [m]. compliance: structure's c > 0 [m/N].
            s: flat position [m]. state: solver state (:meth:`init_state`).
            max_iter: Newton iteration cap (static).
            roughness: None, or for a law with :meth:`rough_nodes` the pair (roughness at
                the nodes [n] m, its contact-filtered value [m]).

        Returns:
            (delta [m], F [N], |r| [m], state); differentiable by the implicit function
            theorem (:func:`wfjax.contact.newton.solve_contact_step`).
        """
        frozen = jax.lax.stop_gradient(self)
        point = self.point(s) if roughness is None else self.rough_point(s, roughness[0])
        point_ng = jax.lax.stop_gradient(point)
        delta, f, r = solve_contact_step(
            lambda d: self.point_force(point, d), delta_free, compliance, max_iter,
            loop_force_fn=lambda d: frozen.point_force(point_ng, d))
        return delta, f, r, state

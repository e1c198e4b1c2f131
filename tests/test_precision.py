"""SimConfig.precision: the float32 time loop is float32 throughout and close to float64."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import wfjax as wf
from wfjax.contact.laws import prepare
from wfjax.loop.run import time_loop
from wfjax.loop.structure import structure
from wfjax.model.vehicle import Vehicle

FLAT = wf.Flat.rounded(depth=0.9e-3, length=0.1)
WIDE = (np.dtype(np.float64), np.dtype(np.complex128))


def _wide_outputs(jaxpr) -> list[str]:
    """Equations of ``jaxpr`` (and of every sub-jaxpr) that produce float64/complex128."""
    found = []
    for eqn in jaxpr.eqns:
        found += [f"{eqn.primitive.name} -> {v.aval}" for v in eqn.outvars
                  if getattr(v.aval, "dtype", None) in WIDE]
        for value in eqn.params.values():
            for sub in value if isinstance(value, (tuple, list)) else (value,):
                inner = getattr(sub, "jaxpr", sub)
                if hasattr(inner, "eqns"):
                    found += _wide_outputs(inner)
    return found


@pytest.mark.parametrize("contact", ["hertz-trajectory", "2d"])
def test_float32_time_loop_has_no_float64_operation(contact):
    config = wf.SimConfig(precision="float32")
    struct = structure(Vehicle.single(), [wf.Wheel()], wf.Track(), config)
    law = prepare(contact, FLAT, wf.Wheel(), wf.Track(), wf.Material(), config)
    closed = jax.make_jaxpr(lambda law, struct: time_loop(
        law, struct, 25.0, 4e-5, -0.3, 0.1, 50, precision="float32"))(law, struct)
    (scan,) = [e for e in closed.jaxpr.eqns  # the time loop (not the static equilibrium's)
               if e.primitive.name == "scan" and e.params["length"] == 49]
    assert _wide_outputs(scan.params["jaxpr"].jaxpr) == []
    carry = [str(v.aval) for v in scan.params["jaxpr"].jaxpr.invars]
    n = int(struct.track.poles.shape[0])
    assert any(f"complex64[{n}]" in c for c in carry)  # the modal state is float32 too


def test_float32_sweep_matches_float64():
    speeds = np.array([60.0, 140.0, 250.0]) / 3.6
    out = {p: wf.sweep(FLAT, speeds, impact_positions=2, contact="hertz-trajectory",
                       config=wf.SimConfig(precision=p), progress=False)
           for p in ("float64", "float32")}
    f64, f32 = out["float64"], out["float32"]
    rel = np.max(np.abs(f32.max_force - f64.max_force) / f64.max_force)
    assert rel < 1e-4  # measured 3.8e-6
    assert rel > 0  # it did run in float32
    np.testing.assert_array_equal(f32.loss_of_contact, f64.loss_of_contact)
    assert f64.loss_of_contact.any()  # 250 km/h loses contact: the flag is exercised
    # float32's contact tolerance is its rounding floor, 8 eps32 |delta_free| (~1e-9 m at
    # 1 mm; wfjax.loop.contacts.newton_tolerance), float64's 1e-15 m
    assert np.max(f32.max_residual) < 2e-9  # measured 5.1e-10 m
    assert np.max(f64.max_residual) <= 1e-15


def test_precision_is_checked():
    with pytest.raises(ValueError, match="precision must be one of"):
        wf.SimConfig(precision="float16")
    with pytest.raises(ValueError, match="does not support contact_mode_3d='direct'"):
        wf.SimConfig(precision="float32", contact_mode_3d="direct")


def test_float32_newton_tolerance_is_its_rounding_floor():
    """float64 keeps the contact Newton's 1e-15 m; float32 stops at 8 eps32 max|delta_free|,
    which it meets in a few iterations, where 1e-15 m (below its rounding of r) is met only by
    chance, so a batch ran every step to the iteration cap (issue 33, item 3)."""
    import jax.numpy as jnp

    from wfjax.contact.newton import bracketed_newton
    from wfjax.loop.contacts import NEWTON_TOL, newton_tolerance

    assert newton_tolerance(jnp.zeros(2)) is NEWTON_TOL  # float64: the same program
    d_free = jnp.linspace(1e-4, 1e-3, 200, dtype=jnp.float32)  # m
    eps = float(jnp.finfo(jnp.float32).eps)
    assert float(newton_tolerance(d_free)) == pytest.approx(8 * eps * 1e-3, rel=1e-6)

    def evaluate(d, aux):  # Hertz, F = C_H d^1.5 [N]
        f, df = jax.value_and_grad(lambda x: 9e10 * jnp.maximum(x, 0.0) ** 1.5)(d)
        return f, df, aux

    def solve(d, tol, max_iter):
        return bracketed_newton(evaluate, d, jnp.float32(1e-9), None, max_iter, tol)[1]

    r_new = jax.vmap(lambda d: solve(d, newton_tolerance(d[None]), 6))(d_free)
    assert np.all(np.asarray(r_new) <= 8 * eps * np.asarray(d_free))  # within 6 iterations
    r_old = jax.vmap(lambda d: solve(d, 1e-15, 30))(d_free)
    assert np.any(np.asarray(r_old) > 1e-15)  # some never reach 1e-15 m: 30 iterations


def test_auto_is_float32_forward_and_float64_for_gradients_and_direct_3d():
    from wfjax.params import loop_precision

    assert wf.SimConfig().precision == "auto"
    assert loop_precision("auto") == "float32"
    assert loop_precision("auto", gradients=True) == "float64"
    assert loop_precision("auto", direct=True) == "float64"
    for p in ("float64", "float32"):  # an explicit choice is kept, gradients or not
        assert loop_precision(p, gradients=True) == p


def test_default_sweep_runs_the_float32_loop_and_returns_float64_arrays():
    speeds = np.array([60.0, 250.0]) / 3.6
    run = {p: wf.sweep(FLAT, speeds, impact_positions=2, contact="hertz-trajectory",
                       config=wf.SimConfig(precision=p), progress=False)
           for p in ("auto", "float32", "float64")}
    np.testing.assert_array_equal(run["auto"].max_force, run["float32"].max_force)
    assert not np.array_equal(run["auto"].max_force, run["float64"].max_force)
    assert np.asarray(run["auto"].max_force).dtype == np.float64  # widened on the way out
    sim = wf.simulate(FLAT, speeds[0], contact="hertz-trajectory", impact_position=0.1)
    assert np.asarray(sim.force).dtype == np.float64
    # t from the uncast float64 step: the same grid as a float64 run's
    ref = wf.simulate(FLAT, speeds[0], contact="hertz-trajectory", impact_position=0.1,
                      config=wf.SimConfig(precision="float64"))
    np.testing.assert_array_equal(np.asarray(sim.t), np.asarray(ref.t))


def test_a_fit_program_takes_its_gradients_in_float64():
    from wfjax.program.core import compile_scenario
    from wfjax.scenario.description import Scenario

    program = compile_scenario(Scenario.of(FLAT, "hertz-trajectory"))
    assert program.statics[2] == "float64"

"""Proof that the capabilities compose over the program core (issue 30, 5a): a fit of a bogie
on a rough rail against detector data, differentiated through the hand-written adjoint, and
the one core behind simulate, sweep and the fits.

The gradient check compares the adjoint's reverse-mode derivatives of the detector model
(the flat wheel's reading: the hard maximum over the bays, then the smooth maximum over the
impact positions the fit uses, temperature 1 kN) with central differences of the same
discrete model, step h = 1e-4 in each of theta = (log depth, length parameter) of
:class:`wfjax.fit.RoundedFlatParam` (about 0.01 % of the depth), within 1 %.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wfjax as wf
from wfjax import fit
from wfjax.model import supports
from wfjax.model.vehicle import Vehicle
from wfjax.program.core import compile_scenario
from wfjax.scenario import roughness as rough_mod
from wfjax.scenario.description import Scenario
from wfjax.scenario.sensors import Detector
from wfjax.scenario.windows import simulation_window

COARSE = wf.SimConfig(max_travel_step=2e-3, max_time_step=5e-5,
                       precision="float64")  # one program to rounding: the float64 loop
STEP = 1e-4  # central-difference step in theta
REL_TOL = 0.01


def _rough_rail():
    return rough_mod.generate(rough_mod.ISO3095_LIMIT, 3, 12.0, x_start=-6.0)


@pytest.mark.slow
def test_bogie_on_a_rough_rail_detector_gradient_matches_central_differences():
    ref = wf.Flat.rounded(0.9e-3, 0.1)
    par = fit.parametrisation_for(ref)
    theta0 = jnp.asarray(par.from_flat(ref))
    model = fit.detector_model([100 / 3.6], ref, Detector(), contact="hertz-trajectory",
                               impact_positions=2, temperature=1e3, vehicle=Vehicle.bogie(),
                               roughness=_rough_rail(), config=COARSE, adjoint=True)
    assert model.program.scenario.per_wheel and model.program.data.roughness is not None

    def f(theta):
        return model(par.to_flat(theta))

    jac = np.asarray(jax.jit(jax.jacrev(f))(theta0)).reshape(-1, theta0.size)
    fj = jax.jit(f)
    for k in range(theta0.size):
        e = np.zeros(theta0.size)
        e[k] = STEP
        fd = (np.asarray(fj(theta0 + e)) - np.asarray(fj(theta0 - e))) / (2 * STEP)
        assert np.all(np.abs(fd - jac[:, k]) <= REL_TOL * np.abs(jac[:, k])), (k, fd, jac)
    # the rough rail and the second wheel matter: the reading differs from a smooth one-wheel run
    alone = fit.detector_model([100 / 3.6], ref, Detector(), contact="hertz-trajectory",
                               impact_positions=2, temperature=1e3, config=COARSE)
    assert abs(float(alone(ref)[0]) - float(f(theta0)[0])) > 1e3


@pytest.mark.slow
def test_fit_flat_takes_a_vehicle_a_rough_rail_and_varying_supports():
    """Max-force data of a bogie's flat wheel on a rough rail over varying supports, simulated
    at a known depth, are
    fitted back from a start 30 % off by the same model (reverse mode through the adjoint)."""
    truth = wf.Flat.new(0.8e-3)
    speeds = np.array([50.0, 80.0, 110.0]) / 3.6
    track = supports.scatter(wf.Track(n_bays=24), key=1, cv=0.3)  # varying pad, ballast stiffness
    kw = dict(contact="hertz-trajectory", config=COARSE, vehicle=Vehicle.bogie(),
              roughness=_rough_rail(), track=track)
    start = wf.Flat.new(0.56e-3)
    bound = fit.parametrisation_for(start).extent_bound  # the fit's windows, for the data too
    data = fit.max_force_model(speeds, truth, impact_positions=2, extent_bound=bound,
                               **kw)(truth)
    res = fit.fit_flat({"speeds": speeds, "max_force": np.asarray(data)}, start,
                       impact_positions=2, mode="reverse", max_iter=40, xtol=1e-6, ftol=1e-12,
                       **kw)
    assert res.params["depth"] == pytest.approx(0.8e-3, rel=2e-3), res.message


def test_one_program_runs_simulate_and_the_fits():
    """simulate's run and a fit's forward evaluation of the same scenario and window are one
    program: the same force history to rounding."""
    flat = wf.Flat.new(0.9e-3)
    v, x = 90 / 3.6, 0.2
    sim = wf.simulate(flat, v, "hertz-profile", impact_position=x, config=COARSE)
    t = np.asarray(sim.t) + simulation_window(flat, v, COARSE)[0] / v  # t = 0 at the impact
    model = fit.history_model(t, v, flat, "hertz-profile", impact_position=x, config=COARSE)
    np.testing.assert_allclose(np.asarray(model(flat)), np.asarray(sim.force), rtol=0,
                               atol=1e-9 * float(np.max(sim.force)))


def test_scenario_is_a_pytree_with_static_structure():
    sc = Scenario.of([wf.Flat.new(0.9e-3), wf.Flat.new(1.2e-3)], "hertz-profile",
                     vehicle=Vehicle.bogie(), roughness=_rough_rail())
    leaves, tree = jax.tree.flatten(sc)
    doubled = jax.tree.unflatten(tree, [2 * np.asarray(a) for a in leaves])
    assert doubled.vehicle == sc.vehicle and doubled.contact == "hertz-profile"
    assert float(doubled.flats[1].depth) == pytest.approx(2.4e-3)
    assert compile_scenario(sc).data.struct.offsets.shape == (2,)


def test_a_joint_goes_into_any_entry_point_as_a_rail_top_input():
    """``roughness=`` takes a rail-top input (a dipped joint) alone or with a rail profile: the
    scenario adds it to the profile, for simulate, sweep and the fits alike."""
    from wfjax.scenario.joint import Joint

    joint, flat, v = Joint(0.3, 0.8e-3, 0.5), wf.Flat.none(), 100 / 3.6
    kw = dict(contact="hertz-profile", impact_position=0.1, config=COARSE)
    alone = wf.simulate(flat, v, roughness=joint, **kw)
    assert float(np.max(alone.force)) == float(np.max(
        wf.simulate(flat, v, roughness=joint.add_to(None), **kw).force))
    rough = _rough_rail()
    both = Scenario.of(flat, "hertz-profile", roughness=[rough, joint]).roughness
    np.testing.assert_array_equal(np.asarray(both.values), np.asarray(joint.add_to(rough).values))
    with pytest.raises(ValueError, match="at most one rail Roughness"):
        Scenario.of(flat, roughness=[rough, rough])

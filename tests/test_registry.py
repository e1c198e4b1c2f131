"""Contact models by name: a user-defined law joins the built-ins through the registry."""

from __future__ import annotations

import jax.numpy as jnp
import pytest

import wfjax as wf
from wfjax.contact import laws, registry
from wfjax.fields import pytree

COARSE = wf.SimConfig(max_travel_step=2e-3, max_time_step=5e-5,
                       precision="float64")  # identities to rounding: float64
FLAT = wf.Flat.rounded(0.9e-3, 0.1)
RUN = dict(impact_position=0.2, track=wf.Track.comparison(), config=COARSE)


@pytree
class MyHertz(laws.HertzTrajectoryLaw):
    """The user's own Hertz spring on the built-in trajectory: F = C max(delta - drop, 0)^1.5."""

    def point_force(self, point, delta):
        return self.c_h * jnp.maximum(delta - point, 0.0) ** 1.5


def _prepare_scaled(scale: float):
    """A prepare function: the built-in trajectory with C_H multiplied by ``scale``."""

    def prepare(flat, wheel, track, material, config, cache_dir=None, **options):
        law = laws.prepare_hertz_trajectory(flat, wheel, track, material, config, cache_dir,
                                            **options)
        return MyHertz(scale * law.c_h, law.s_grid, law.drop, law.flat)

    return prepare


@pytest.fixture
def user_laws():
    """Registers "my-law" (C_H as built in) and "my-stiff-law" (2 C_H); removed afterwards."""
    added = {"my-law": 1.0, "my-stiff-law": 2.0}
    for name, scale in added.items():
        registry.register(name, _prepare_scaled(scale), f"test: Hertz trajectory, {scale} C_H")
    yield tuple(added)
    for name in added:
        registry.unregister(name)


@pytest.mark.slow
def test_a_registered_law_runs_in_simulate(user_laws):
    """The user's law with the built-in constant gives the built-in's forces; twice the
    constant gives 2^(-2/3) of the static approach and a larger impact force."""
    assert set(user_laws) <= set(registry.names())
    built_in = wf.simulate(FLAT, 100 / 3.6, contact="hertz-trajectory", **RUN)
    mine = wf.simulate(FLAT, 100 / 3.6, contact="my-law", **RUN)
    stiff = wf.simulate(FLAT, 100 / 3.6, contact="my-stiff-law", **RUN)
    scale = float(jnp.max(built_in.force))
    assert float(jnp.max(jnp.abs(mine.force - built_in.force))) <= 1e-12 * scale
    assert float(stiff.approach[0]) == pytest.approx(2 ** (-2 / 3) * float(built_in.approach[0]),
                                                     rel=1e-9)
    assert float(stiff.max_force) > float(built_in.max_force)  # here +0.8 %


def test_unknown_names_are_one_line_errors():
    with pytest.raises(ValueError, match="got 'no-such-law'") as err:
        laws.prepare("no-such-law", FLAT, wf.Wheel(), wf.Track(), wf.Material(), COARSE)
    assert "\n" not in str(err.value) and "hertz-trajectory" in str(err.value)
    with pytest.raises(ValueError, match="'no-such-law'"):
        registry.unregister("no-such-law")


def test_taken_names_are_refused(user_laws):
    for name in ("hertz-trajectory", user_laws[0]):
        with pytest.raises(ValueError, match=f"{name!r} is already registered"):
            registry.register(name, _prepare_scaled(3.0), "another law")
    with pytest.raises(ValueError, match="built in"):
        registry.unregister("3d")
    assert registry.get(user_laws[0]) is not None


def test_prepare_rejects_unknown_options_and_ignores_other_laws_ones():
    args = (FLAT, wf.Wheel(), wf.Track(), wf.Material(), COARSE)
    with pytest.raises(ValueError, match=r"unknown options \['depth_bound'\]"):
        laws.prepare_hertz_profile(*args, depth_bound=1e-3)
    law = laws.prepare_hertz_profile(*args, max_depth=1e-3, family=None)
    assert isinstance(law, laws.HertzProfileLaw)

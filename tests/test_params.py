"""Parameter pytrees: defaults of Tables 1 and 2, leaves reachable by jax, validation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wfjax as wf


def test_table_defaults():
    w, t, m = wf.Wheel(), wf.Track(), wf.Material()
    assert (w.wheelset_mass, w.suspension_stiffness) == (593.0, 1.12e6)
    assert w.suspension_damping == 13.2e3
    assert (w.small_mass, w.contact_stiffness, w.contact_damping) == (3.0, 2.4e9, 155e3)
    assert (w.radius, w.preload) == (0.45, 118e3)
    assert (t.bending_stiffness, t.shear_stiffness, t.rail_mass) == (6.4e6, 250e6, 60.0)
    assert (t.sleeper_spacing, t.pad_stiffness, t.pad_damping) == (0.65, 120e6, 16e3)
    assert (t.sleeper_mass, t.ballast_stiffness, t.ballast_damping) == (125.0, 140e6, 165e3)
    assert t.rail_head_radius == 0.30 and wf.Track.comparison().rail_head_radius == 0.45
    assert (t.n_bays, t.elements_per_bay, t.ends) == (4, 26, "auto")  # issue 33: the least cost
    # within 0.5 % (end networks on the default track: the guards lengthen it to the case)
    assert (m.youngs_modulus, m.poisson_ratio) == (210e9, 0.3)


def test_numbers_are_leaves_and_choices_static():
    flat = wf.Flat.rounded(0.9e-3, 0.1)
    leaves = jax.tree_util.tree_leaves(flat)
    assert 0.9e-3 in leaves and 0.1 in leaves and "rounded" not in leaves
    assert len(jax.tree_util.tree_leaves(wf.Track())) == 12  # n_bays, elements_per_bay static
    g = jax.grad(lambda f: f.depth * f.length)(flat)
    assert g.depth == pytest.approx(0.1) and g.length == pytest.approx(0.9e-3)
    depths = jnp.array([0.5e-3, 0.9e-3])
    batched = jax.vmap(lambda d: wf.geometry.profile_deviation(
        wf.Flat("rounded", d, 0.1), jnp.array([0.0])))(depths)
    np.testing.assert_allclose(batched[:, 0], depths)


@pytest.mark.parametrize(
    "build, message",
    [
        (lambda: wf.Flat.new(-1e-3), "Flat.depth"),
        (lambda: wf.Flat.new(0.0), "Flat.depth"),
        (lambda: wf.Flat.new(6e-3), "Flat.depth"),
        (lambda: wf.Flat.new(float("nan")), "Flat.depth"),
        (lambda: wf.Flat.rounded(0.9e-3, 0.05), "pi/2"),
        (lambda: wf.Flat.rounded(0.9e-3, float("inf")), "Flat.length"),
        (lambda: wf.Wheel(wheelset_mass=0.0), "Wheel.wheelset_mass"),
        (lambda: wf.Wheel(radius=-0.45), "Wheel.radius"),
        (lambda: wf.Track(pad_stiffness=-1.0), "Track.pad_stiffness"),
        (lambda: wf.Track(elements_per_bay=0), "Track.elements_per_bay"),
        (lambda: wf.Track(rail_head_radius=float("nan")), "Track.rail_head_radius"),
        (lambda: wf.Material(poisson_ratio=0.5), "Material.poisson_ratio"),
        (lambda: wf.Material(youngs_modulus=0.0), "Material.youngs_modulus"),
        (lambda: wf.Flat.from_profile([0, 1e-3, 1e-3], [0, 1e-4, 0]), "strictly increasing"),
        (lambda: wf.Flat.from_profile([0, 1e-3, 2e-3], [0, -1e-4, 0]), "profile_z"),
        (lambda: wf.Flat.from_profile([0, 1e-3, 2e-3], [0, np.nan, 0]), "finite"),
        (lambda: wf.Flat.from_profile([-2.0, 0, 2.0], [0, 1e-4, 0]), "circumference"),
        (lambda: wf.Flat("square", 1e-3, 0.1), "Flat.kind"),
        (lambda: wf.SimConfig(time_step=-1e-5), "SimConfig.time_step"),
        (lambda: wf.SimConfig(contact_mode_3d="fast"), "contact_mode_3d"),
    ],
)
def test_bad_input_raises_clear_error(build, message):
    with pytest.raises(ValueError, match=message):
        build()


def test_rounded_length_boundary_is_accepted():
    l0 = wf.params.new_flat_length(0.9e-3)
    wf.Flat.rounded(0.9e-3, np.pi / 2 * l0)
    assert wf.Flat.rounded_relative(0.9e-3, 1.76).length == pytest.approx(1.76 * l0)


def test_unit_helpers():
    assert wf.kmh(36.0) == pytest.approx(10.0)
    assert wf.mm(0.9) == pytest.approx(0.9e-3)


def test_flat_longer_than_a_tenth_of_the_circumference_is_refused():
    with pytest.raises(ValueError, match=r"Flat.length must be in \(0, 300\] mm"):
        wf.Flat.rounded(0.9e-3, 5.0)
    assert float(wf.Flat.rounded(0.9e-3, 0.3).length) == 0.3

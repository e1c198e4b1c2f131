"""A dipped rail joint (issue 30, item 5b): the dip's geometry, its checks, how it joins the
rail roughness, the case file and the command line, and Jenkins' P2 estimate."""

import json
import math

import numpy as np
import pytest

import wfjax as wf
from wfjax import case as C
from wfjax.cli import main
from wfjax.model import track as T
from wfjax.scenario import roughness as R
from wfjax.scenario.joint import (
    MARGIN,
    MAX_SLOPE,
    Joint,
    equivalent_track,
    jenkins_p2,
    rail_span,
)

F64 = wf.SimConfig(precision="float64")  # identities to rounding: the float64 loop

D, L, X0 = 1e-3, 0.5, 0.1  # a 1 mm dip over 0.5 m centred 0.1 m past the middle sleeper


def _v(x, x0=X0, d=D, l=L):
    """The v dip written out on its own (not through Joint.profile)."""
    return -d * np.clip(1.0 - 2.0 * np.abs(np.asarray(x) - x0) / l, 0.0, None)


def _cosine(x, x0=X0, d=D, l=L):
    """The cosine dip written out on its own: -d cos^2(pi u) for |u| <= 1/2."""
    u = (np.asarray(x) - x0) / l
    return np.where(np.abs(u) <= 0.5, -d * np.cos(np.pi * u) ** 2, 0.0)


# -- geometry -----------------------------------------------------------------------------
@pytest.mark.parametrize("shape, by_hand", [("cosine", _cosine), ("v", _v)])
def test_profile_depth_length_symmetry_and_area(shape, by_hand):
    j = Joint(X0, D, L, shape)
    assert j.profile(X0) == pytest.approx(-D, abs=1e-18)  # deepest at the joint
    assert j.start == pytest.approx(X0 - L / 2) and j.end == pytest.approx(X0 + L / 2)
    eps = 1e-6
    outside = np.array([j.start - eps, j.end + eps, j.start - 1.0, j.end + 3.0])
    assert np.all(j.profile(outside) == 0.0)  # level rail outside the dip
    assert np.all(j.profile([j.start + 0.01, j.end - 0.01]) < 0)  # dipped inside
    u = np.linspace(0.0, 0.3, 61)
    assert np.allclose(j.profile(X0 + u), j.profile(X0 - u), rtol=0, atol=1e-15)  # symmetric
    x = np.linspace(X0 - 0.4, X0 + 0.4, 8001)
    assert np.allclose(j.profile(x), by_hand(x), rtol=0, atol=1e-15)
    area = np.sum(j.profile(x)) * (x[1] - x[0])  # both dips hold d l / 2 of missing rail
    assert area == pytest.approx(-D * L / 2, rel=1e-4)


def test_total_angle_is_the_change_of_slope_across_the_bottom():
    h = 1e-6
    v = Joint(X0, D, L, "v")
    slope_in = (v.profile(X0) - v.profile(X0 - h)) / h
    slope_out = (v.profile(X0 + h) - v.profile(X0)) / h
    assert slope_in == pytest.approx(-2 * D / L, rel=1e-6)
    assert slope_out - slope_in == pytest.approx(4 * D / L, rel=1e-6) == v.total_angle
    c = Joint(X0, D, L, "cosine")
    steep = [(c.profile(X0 + s * L / 4 + h) - c.profile(X0 + s * L / 4 - h)) / (2 * h)
             for s in (-1, 1)]  # steepest at the quarter points: -+ pi d / l
    assert steep == pytest.approx([-math.pi * D / L, math.pi * D / L], rel=1e-6)
    assert steep[1] - steep[0] == pytest.approx(c.total_angle, rel=1e-6)
    curvature = (c.profile(X0 + h) - 2 * c.profile(X0) + c.profile(X0 - h)) / h**2
    assert 1 / curvature == pytest.approx(c.min_radius, rel=1e-3) == L**2 / (2 * np.pi**2 * D)


# -- checks ---------------------------------------------------------------------------------
@pytest.mark.parametrize("kwargs, words", [
    ({"depth": -1e-3}, ["Joint.depth", "-0.001", "(0, 0.005] m"]),
    ({"depth": 6e-3}, ["Joint.depth", "0.006", "0-5 mm"]),
    ({"depth": float("nan")}, ["Joint.depth", "nan", "finite"]),
    ({"length": 0.05}, ["Joint.length", "0.05", "[0.1, 2] m"]),
    ({"length": 3.0}, ["Joint.length", "3.0", "[0.1, 2] m"]),
    ({"position": 800.0}, ["Joint.position", "800.0", "[-750, 750] m"]),
    ({"position": "0"}, ["Joint.position", "'0'", "a number"]),
    ({"depth": True}, ["Joint.depth", "True", "a number"]),
    ({"shape": "u"}, ["Joint.shape", "'u'", "'cosine', 'v'"]),
    ({"depth": 3e-3, "length": 0.15},
     ["Joint.length", "0.15", f"{MAX_SLOPE:g} rad", ">= 0.1885 m"]),
    ({"depth": 3e-3, "length": 0.1, "shape": "v"}, ["Joint.length", "0.1", ">= 0.12 m"]),
])
def test_bad_values_name_the_field_the_value_and_the_range(kwargs, words):
    with pytest.raises(ValueError) as err:
        Joint(**({"position": 0.0, "depth": D, "length": L} | kwargs))
    message = str(err.value)
    assert "\n" not in message
    for w in words:
        assert w in message, (w, message)


def test_a_wheel_must_follow_the_cosine_bottom():
    j = Joint(0.0, 1e-3, 0.12)  # bottom radius l^2 / (2 pi^2 d) = 0.73 m
    j.check_wheel(0.45)
    with pytest.raises(ValueError, match=r"Joint.length must be >= 0.1405 m .* 1 m wheel"):
        j.check_wheel(1.0)
    Joint(0.0, 1e-3, 0.12, "v").check_wheel(1.0)  # a kink: the contact filter rounds it


# -- as rail roughness -----------------------------------------------------------------------
def test_add_to_none_makes_a_rail_profile_over_the_model_rail():
    j = Joint(X0, D, L)
    rough = j.add_to(None)
    assert not rough.periodic and float(rough.spacing) == 5e-4
    x = rough.x
    lo, hi = rail_span()
    half = 0.5 * wf.params.ABSORBING_BAYS * wf.Track().sleeper_spacing  # rail_span: >= 24 bays
    assert (lo, hi) == pytest.approx((-half, half))
    assert x[0] <= lo + 1e-9 and x[-1] >= hi - 1e-9 and x[0] > lo - 5e-4
    assert np.min(np.abs(x - X0)) < 1e-12  # a sample on the joint centre
    assert np.allclose(np.asarray(rough.values), _cosine(x), rtol=0, atol=1e-15)
    assert float(np.min(rough.values)) == pytest.approx(-D, abs=1e-15)
    short = j.add_to(None, span=(-1.0, 1.0), spacing=1e-3)
    assert short.x[0] == pytest.approx(-1.0) and short.x[-1] == pytest.approx(1.0)
    assert float(short.spacing) == 1e-3
    far = Joint(5.0, D, L).add_to(None, span=(-1.0, 1.0))  # widened to the dip plus a margin
    assert far.x[-1] == pytest.approx(5.0 + L / 2 + MARGIN)
    with pytest.raises(ValueError, match="spacing 2 mm is too coarse"):
        j.add_to(None, spacing=2e-3)
    with pytest.raises(ValueError, match="span must be finite with x_lo < x_hi"):
        j.add_to(None, span=(1.0, -1.0))


def test_add_to_keeps_the_grid_and_every_realisation_and_extends_by_holding_ends():
    rng = np.random.default_rng(0)
    base = R.Roughness(-0.5, 2.5e-4, rng.normal(0, 20e-6, (3, 2001)))  # x in [-0.5, 0]
    j = Joint(-0.1, 0.5e-3, 0.4, "v")  # dip in [-0.3, 0.1]: partly beyond the profile
    out = j.add_to(base)
    assert float(out.spacing) == float(base.spacing) and float(out.x_start) == -0.5
    n_old = base.values.shape[-1]
    values = np.asarray(out.values)
    assert values.shape[0] == 3 and values.shape[-1] > n_old
    assert out.x[-1] >= j.end + MARGIN - 1e-12  # covers the dip plus the margin
    assert np.allclose(out.x[:n_old], base.x, rtol=0, atol=1e-12)  # same samples
    held = np.concatenate([base.values, np.repeat(base.values[:, -1:], values.shape[-1] - n_old,
                                                  axis=1)], axis=1)
    assert np.allclose(values, held + _v(out.x, -0.1, 0.5e-3, 0.4), rtol=0, atol=1e-15)
    before = Joint(-0.9, 0.5e-3, 0.4).add_to(base)  # extends to the left too
    assert float(before.x_start) < -0.5 - 0.4 and before.x[-1] == pytest.approx(0.0)
    assert np.allclose(np.asarray(before.values)[:, -n_old:] - base.values,
                       Joint(-0.9, 0.5e-3, 0.4).profile(base.x), rtol=0, atol=1e-15)
    wheel = R.Roughness(0.0, 1e-3, np.zeros(2827), periodic=True)
    with pytest.raises(ValueError, match=r"rail roughness .*\(a wheel profile\)"):
        j.add_to(wheel)


def test_a_joint_deeper_than_roughness_holds_is_refused_in_one_line():
    base = R.Roughness(-1.0, 1e-3, np.full(2001, 4e-3))  # raised 4 mm: room for 1 mm below 0
    with pytest.raises(ValueError) as err:
        Joint(0.0, 2e-3, 0.5).add_to(R.Roughness(-1.0, 1e-3, np.full(2001, -4e-3)))
    msg = str(err.value)
    assert "\n" not in msg and "Joint.depth = 0.002 m" in msg and "MAX_AMPLITUDE" in msg
    assert "allowed now: depth <= 1 mm" in msg
    assert float(np.min(Joint(0.0, 2e-3, 0.5).add_to(base).values)) == pytest.approx(2e-3)


def test_realistic_joints_up_to_3_mm_make_rail_profiles():
    rough = Joint(0.0, 3e-3, 0.5).add_to(None)
    assert float(np.min(rough.values)) == pytest.approx(-3e-3)


# -- end to end ----------------------------------------------------------------------------
@pytest.mark.parametrize("shape, by_hand", [("cosine", _cosine), ("v", _v)])
def test_simulate_with_the_joint_equals_the_dip_entered_by_hand(shape, by_hand):
    rough = Joint(X0, D, L, shape).add_to(None)
    hand = R.Roughness(-22.75, 5e-4, by_hand(-22.75 + 5e-4 * np.arange(91001)))
    speed = 100 / 3.6
    a = wf.simulate(wf.Flat.none(), speed, contact="hertz-profile", roughness=rough, config=F64)
    b = wf.simulate(wf.Flat.none(), speed, contact="hertz-profile", roughness=hand, config=F64)
    assert float(a.max_force) == pytest.approx(float(b.max_force), rel=1e-9)
    assert np.allclose(np.asarray(a.force), np.asarray(b.force), rtol=0, atol=1e-9 * 118e3)
    assert float(a.max_force) > 140e3 and float(a.min_force) < 95e3  # the dip shows


# -- case file and command line ------------------------------------------------------------
def test_case_file_joint_section_adds_the_dip(tmp_path):
    cfg = tmp_path / "case.toml"
    cfg.write_text('[joint]\nposition = 0.2\ndepth_mm = 0.8\nlength = 0.6\nshape = "v"\n'
                   '[roughness]\npreset = "iso3095"\nrealisations = 2\nlength = 4.0\n')
    case = C.resolve("sweep", str(cfg), environ={})
    assert case.joint() == Joint(0.2, 0.8e-3, 0.6, "v")
    rail, wheel = case.roughness(0.45)
    plain = C.resolve("sweep", str(cfg), {"joint.depth": None}, environ={})
    assert plain.joint() is None
    alone, _ = plain.roughness(0.45)
    assert wheel is None and np.shape(rail.values) == np.shape(alone.values) == (2, 16000)
    dip = np.asarray(rail.values) - np.asarray(alone.values)
    assert np.allclose(dip, _v(rail.x, 0.2, 0.8e-3, 0.6), rtol=0, atol=1e-15)
    none = C.resolve("simulate", None, {"joint.depth": 1e-3}, environ={})
    rail, _ = none.roughness(0.45)
    half = 0.5 * wf.params.ABSORBING_BAYS * wf.Track().sleeper_spacing
    assert rail.x[0] == pytest.approx(-half) and float(np.min(rail.values)) == -1e-3


@pytest.mark.parametrize("flags, words", [
    ({"joint.position": 5.0}, ["joint.position = 5 m", "off the wheel's path",
                               "config.run_in"]),
    ({"joint.position": 30.0}, ["[joint]", "model rail [-7.8, 7.8] m"]),  # the default track
    ({"joint.length": 0.1, "wheel.radius": 0.8, "flat.kind": "new"},
     ["[joint]", "Joint.length must be >= 0.1257 m", "0.8 m wheel"]),
])
def test_case_refuses_a_joint_that_would_not_work(flags, words):
    with pytest.raises(C.CaseError) as err:
        C.resolve("simulate", None, {"joint.depth": 1e-3} | flags, environ={})
    msg = str(err.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg, (w, msg)


def _peak(out) -> float:
    return json.loads((out / "simulate.json").read_text())["max_force_kN"]


@pytest.mark.slow
def test_cli_joint_flags_change_the_peak_force_and_bad_ones_stop_with_one_line(tmp_path,
                                                                             capsys):
    base = ["simulate", "--contact", "hertz-profile", "--flat", "new", "--depth-mm", "0.05"]
    assert main([*base, "--out", str(tmp_path / "plain")]) == 0
    joint = ["--joint-depth-mm", "1", "--joint-length-m", "0.4", "--joint-shape", "v",
             "--joint-position-m", "0.1"]
    assert main([*base, *joint, "--out", str(tmp_path / "joint")]) == 0
    plain, dipped = _peak(tmp_path / "plain"), _peak(tmp_path / "joint")
    assert dipped > plain + 20.0, (plain, dipped)  # kN
    case = json.loads((tmp_path / "joint" / "simulate.json").read_text())["case"]
    assert case["joint"] == {"position": 0.1, "depth": 0.001, "length": 0.4, "shape": "v"}
    capsys.readouterr()
    for bad, words in ((["--joint-depth-mm", "-1"], ["--joint-depth-mm", "(0, 5] mm"]),
                       (["--joint-depth-mm", "1", "--joint-length-m", "0.05"],
                        ["--joint-length-m", "[0.1, 2] m"]),
                       (["--joint-depth-mm", "1", "--joint-position-m", "3"],
                        ["joint.position = 3 m", "off the wheel's path"])):
        out = tmp_path / "bad"
        assert main([*base, *bad, "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and not out.exists(), err
        for w in words:
            assert w in err[0], (w, err[0])


# -- Jenkins' P2 -------------------------------------------------------------------------------
def test_jenkins_p2_formula_and_its_derivation():
    p0, mu, mt, kt, ct, v, angle = 118e3, 596.0, 66.0, 135e6, 70e3, 30.0, 0.01
    bracket = 1 - ct * math.pi / (4 * math.sqrt(kt * (mu + mt)))
    want = p0 + angle * v * math.sqrt(mu / (mu + mt)) * bracket * math.sqrt(kt * mu)
    assert jenkins_p2(v, angle, p0, mu, mt, kt, ct) == pytest.approx(want, rel=1e-14)
    assert jenkins_p2(v, 0.0, p0, mu, mt, kt, ct) == p0
    # undamped: momentum mu * angle * v shared with the track mass, then the pair bounces on
    # the track spring; the spring force peaks at kt * amplitude
    m = mu + mt
    u0 = mu * angle * v / m
    t = np.linspace(0, 0.02, 200001)
    omega = math.sqrt(kt / m)
    assert jenkins_p2(v, angle, p0, mu, mt, kt, 0.0) - p0 == pytest.approx(
        kt * np.max(u0 / omega * np.sin(omega * t)), rel=1e-8)
    # damped: the bracket is the first peak's decay, exp(-zeta pi / 2) to first order in the
    # damping ratio zeta; at zeta = 0.17 it lies 3 % below the damped bounce's spring force
    zeta = ct / (2 * math.sqrt(kt * m))
    wd = omega * math.sqrt(1 - zeta**2)
    x = u0 / wd * np.exp(-zeta * omega * t) * np.sin(wd * t)
    assert bracket == pytest.approx(1 - zeta * math.pi / 2, rel=1e-14)
    damped = jenkins_p2(v, angle, p0, mu, mt, kt, ct) - p0
    assert 0.95 * kt * np.max(x) < damped < kt * np.max(x)
    speeds = np.array([10.0, 20.0, 40.0])
    assert np.allclose(jenkins_p2(speeds, angle, p0, mu, mt, kt, ct) - p0,
                       (want - p0) * speeds / v)
    with pytest.raises(ValueError, match=r"track_stiffness must be finite and in \(0, inf\) "
                                         r"N/m, got -1"):
        jenkins_p2(v, angle, p0, mu, mt, -1, ct)
    with pytest.raises(ValueError, match=r"speed must be in \(0, 150\] m/s"):
        jenkins_p2(200.0, angle, p0, mu, mt, kt, ct)


def test_equivalent_track_comes_from_the_models_receptance():
    track = wf.Track()
    eq = equivalent_track(track, 596.0, x=0.0)
    assert 1 / eq.stiffness == pytest.approx(T.static_deflection(track, 1.0), rel=1e-12)
    assert eq.frequency == pytest.approx(math.sqrt(eq.stiffness / (596.0 + eq.mass)) / (2 * np.pi),
                                         rel=1e-6)
    omega = 2 * np.pi * eq.frequency
    dyn = 1 / T.receptance(track, [eq.frequency], 0.0)[0]  # the mass-spring-damper matches
    assert eq.stiffness - omega**2 * eq.mass + 1j * omega * eq.damping == pytest.approx(
        dyn, rel=1e-6)
    assert 40 < eq.mass < 100 and 120e6 < eq.stiffness < 150e6 and 50e3 < eq.damping < 90e3
    j = Joint(0.0, D, 0.4, "v")
    wheel = wf.Wheel()
    assert j.p2(100 / 3.6) == pytest.approx(jenkins_p2(
        100 / 3.6, 4 * D / 0.4, 118e3, float(wheel.wheelset_mass + wheel.small_mass), eq.mass,
        eq.stiffness, eq.damping), rel=1e-6)

"""The hand-written adjoint of the time loop (wfjax.loop.adjoint, issue 20 item 4): the same forward
values as run_scan, the same reverse-mode gradients as plain autodiff through run_scan, and
central finite differences for the 3D family.

The default set (about a minute on 2 cores: each test compiles a reverse-mode program)
checks one Hertz law against plain autodiff, the 3D family against finite differences and
the errors; the other laws, the vehicle, float32, roughness, vmap and the fit option are
``slow``. Short runs (400 steps of 30 us at 100 km/h, the flat's impact included) and a
small 3D family (2 mm elements, forces to 300 kN, as tests/test_family.py).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wfjax as wf
from wfjax import fit
from wfjax.contact import family_build, family_spec, laws
from wfjax.contact.table_law import TableLaw
from wfjax.fit.optimise import _objective
from wfjax.loop import adjoint as adj
from wfjax.loop.run import run_scan
from wfjax.loop.structure import structure
from wfjax.model.vehicle import Vehicle, placement
from wfjax.program.laws import loop_roughness
from wfjax.scenario import roughness as rough_mod

V, DT, N = 100 / 3.6, 3e-5, 400
IMPACT = 0.1
X0 = IMPACT - 0.2  # the flat's centre reaches the contact after 0.2 m (of 0.33 m)
TH0 = jnp.array([0.9e-3, 0.1])  # depth, length [m]
CONFIG = wf.SimConfig(contact_element=2e-3)
WHEEL, TRACK, MAT = wf.Wheel(), wf.Track(n_bays=24), wf.Material()
REL = 1e-8


@pytest.fixture(scope="module")
def struct():
    return structure(Vehicle.single(), [WHEEL], TRACK, CONFIG)


@pytest.fixture(scope="module")
def fam(tmp_path_factory):
    # R_R = R_W = 0.45 m as tests/test_family.py (2 mm elements resolve that contact)
    spec = family_spec.family_spec("rounded", [0.6e-3, 0.9e-3], [1.7, 1.8], 0.45, 0.45, MAT,
                              element_size=2e-3, max_force=300e3)
    return family_build.build_family(spec, MAT, cache_dir=tmp_path_factory.mktemp("family"))


def _flat(th):
    return wf.Flat("rounded", th[0], th[1], extent_bound=0.06)


def _law(contact, th, fam=None):
    if contact == "3d":
        return laws.parametric_law(fam, th[0], th[1])
    return laws.prepare(contact, _flat(th), WHEEL, TRACK, MAT, CONFIG)


def _misfit(hist):
    """A loss that reaches every step: the peak, the squared forces and the approach."""
    f = hist["force"]
    return jnp.max(f) / 1e5 + jnp.sum((f / 1e5) ** 2) + jnp.sum(hist["approach"]) * 1e3


def _close(a, b, rel=REL):
    a, b = np.asarray(a), np.asarray(b)
    assert np.max(np.abs(a - b)) <= rel * np.max(np.abs(b)), (a, b)


@pytest.mark.slow
@pytest.mark.parametrize("contact", ["hertz-trajectory", "hertz-profile", "2d", "3d"])
def test_gradient_matches_plain_autodiff_and_forward_is_bit_identical(contact, struct, fam):
    def loss(th, runner):
        return _misfit(runner(_law(contact, th, fam), struct, V, DT, X0, IMPACT, N))

    plain = jax.jit(jax.grad(lambda th: loss(th, run_scan)))(TH0)
    ours = jax.jit(jax.grad(lambda th: loss(th, adj.run_adjoint)))(TH0)
    assert np.all(np.abs(np.asarray(plain)) > 0)
    _close(ours, plain)
    law = _law(contact, TH0, fam)
    want = run_scan(law, struct, V, DT, X0, IMPACT, N)
    got = adj.run_adjoint(law, struct, V, DT, X0, IMPACT, N)
    assert want.keys() == got.keys()
    for k in want:
        np.testing.assert_array_equal(np.asarray(got[k]), np.asarray(want[k]), err_msg=k)


@pytest.mark.slow
def test_table_law_leaves_get_the_plain_cotangents(struct, fam):
    """The exact-table law's arrays (onset, force, slope columns) as the differentiated leaves."""
    table = TableLaw(laws.parametric_law(fam, TH0[0], TH0[1]).table)

    def loss(law, runner):
        return _misfit(runner(law, struct, V, DT, X0, IMPACT, N))

    plain = jax.jit(jax.grad(lambda lw: loss(lw, run_scan)))(table)
    ours = jax.jit(jax.grad(lambda lw: loss(lw, adj.run_adjoint)))(table)
    for name in ("onset", "force", "slope"):
        a, b = getattr(ours.table, name), getattr(plain.table, name)
        assert np.max(np.abs(np.asarray(b))) > 0, name
        _close(a, b)


@pytest.mark.slow
@pytest.mark.parametrize("contact", ["hertz-trajectory", "3d"])
def test_two_wheel_vehicle(contact, struct, fam):
    vehicle = Vehicle.bogie()
    vstruct = structure(vehicle, [WHEEL, WHEEL], TRACK, CONFIG)
    smooth = (laws.parametric_law(fam, jnp.asarray(0.6e-3), jnp.asarray(0.095)) if contact == "3d"
              else laws.prepare(contact, wf.Flat.none(), WHEEL, TRACK, MAT, CONFIG))
    x_imp = placement(vehicle, 0.65) + IMPACT

    def loss(th, runner):
        hist = runner((_law(contact, th, fam), smooth), vstruct, V, DT, x_imp - 0.2, x_imp, N)
        return _misfit(hist) + jnp.max(hist["force"][:, 1]) / 1e5

    plain = jax.jit(jax.grad(lambda th: loss(th, run_scan)))(TH0)
    ours = jax.jit(jax.grad(lambda th: loss(th, adj.run_adjoint)))(TH0)
    _close(ours, plain)
    pair = (_law(contact, TH0, fam), smooth)
    want = run_scan(pair, vstruct, V, DT, x_imp - 0.2, x_imp, N)
    got = adj.run_adjoint(pair, vstruct, V, DT, x_imp - 0.2, x_imp, N)
    for k in ("force", "approach", "wheel_disp", "rail_disp"):
        np.testing.assert_array_equal(np.asarray(got[k]), np.asarray(want[k]), err_msg=k)



@pytest.mark.slow
def test_two_wheels_on_a_track_whose_supports_vary():
    # the backward pass's step compliance reads the vehicle's tables along the whole rail,
    # as the forward's (it once built its cross table per bay)
    from wfjax.model import supports

    track, vehicle = supports.void_sleeper(TRACK, TRACK.n_bays // 2), Vehicle.bogie()
    vstruct = structure(vehicle, [WHEEL, WHEEL], track, CONFIG)
    smooth = laws.prepare("hertz-profile", wf.Flat.none(), WHEEL, track, MAT, CONFIG)

    def loss(th, runner):
        law = laws.prepare("hertz-profile", _flat(th), WHEEL, track, MAT, CONFIG)
        hist = runner((law, smooth), vstruct, V, DT, 0.7 - 0.2, 0.7, N)
        return _misfit(hist) + jnp.max(hist["force"][:, 1]) / 1e5

    plain = jax.jit(jax.grad(lambda th: loss(th, run_scan)))(TH0)
    ours = jax.jit(jax.grad(lambda th: loss(th, adj.run_adjoint)))(TH0)
    _close(ours, plain)

@pytest.mark.slow
def test_float32(struct):
    def loss(th, runner):
        law = _law("hertz-trajectory", th)
        return _misfit(runner(law, struct, V, DT, X0, IMPACT, N, precision="float32"))

    plain = jax.jit(jax.grad(lambda th: loss(th, run_scan)))(TH0)
    ours = jax.jit(jax.grad(lambda th: loss(th, adj.run_adjoint)))(TH0)
    ref64 = jax.jit(jax.grad(lambda th: _misfit(adj.run_adjoint(
        _law("hertz-trajectory", th), struct, V, DT, X0, IMPACT, N))))(TH0)
    assert ours.dtype == TH0.dtype
    _close(ours, plain, 1e-3)
    _close(ours, ref64, 1e-2)


@pytest.mark.slow
@pytest.mark.parametrize("contact", ["hertz-trajectory", "2d"])
def test_roughness(contact, struct):
    """Rail roughness: a point law's filtered shift (hertz), the bedding's node by node (2d)."""
    x = np.arange(-0.5, 0.6, 2.5e-4)
    rail = rough_mod.Roughness(float(x[0]), 2.5e-4, 5e-6 * np.sin(2 * np.pi * x / 0.04))
    rough = loop_roughness(rail)

    def loss(th, runner):
        return _misfit(runner(_law(contact, th), struct, V, DT, X0, IMPACT, N,
                              roughness=rough))

    plain = jax.jit(jax.grad(lambda th: loss(th, run_scan)))(TH0)
    ours = jax.jit(jax.grad(lambda th: loss(th, adj.run_adjoint)))(TH0)
    _close(ours, plain)


@pytest.mark.slow
def test_under_vmap_and_batched_runs(struct):
    """vmap of adjoint_loop over runs, adjoint_runs over the same batch, and plain autodiff
    agree; the batch's forward equals vmap of run_scan bit for bit."""
    speeds = jnp.array([60.0, 100.0]) / 3.6
    dts = jnp.array([4e-5, 3e-5])
    x0s, imps = jnp.array([X0, X0 + 0.05]), jnp.array([IMPACT, IMPACT + 0.05])

    def peak(hist):
        return jnp.sum(jnp.max(hist["force"], axis=-1)) / 1e5

    def vmapped(runner):
        def loss(th):
            law = _law("hertz-trajectory", th)
            return peak(jax.vmap(lambda v, d, a, b: runner(law, struct, v, d, a, b, N))(
                speeds, dts, x0s, imps))
        return loss

    def batched(th):
        return peak(adj.run_adjoint_runs(_law("hertz-trajectory", th), struct, speeds, dts,
                                         x0s, imps, N))

    plain = jax.jit(jax.grad(vmapped(run_scan)))(TH0)
    _close(jax.jit(jax.grad(vmapped(adj.run_adjoint)))(TH0), plain)
    _close(jax.jit(jax.grad(batched))(TH0), plain)
    law = _law("hertz-trajectory", TH0)
    # every input an argument, not a constant of the program (XLA folds constants)
    want = jax.jit(lambda lw, st, *runs: jax.vmap(lambda v, d, a, b: run_scan(
        lw, st, v, d, a, b, N))(*runs))(law, struct, speeds, dts, x0s, imps)
    got = adj.run_adjoint_runs(law, struct, speeds, dts, x0s, imps, N)
    for k in ("force", "approach"):
        np.testing.assert_array_equal(np.asarray(got[k]), np.asarray(want[k]), err_msg=k)


@pytest.mark.slow
def test_3d_family_max_force_gradient_matches_central_differences(struct, fam):
    speeds = jnp.array([60.0, 120.0]) / 3.6
    n = 500
    dts = 0.3 / speeds / n
    x0s, imps = jnp.full(2, IMPACT - 0.12), jnp.full(2, IMPACT)

    def peak(th):
        hist = adj.run_adjoint_runs(_law("3d", th, fam), struct, speeds, dts, x0s, imps, n)
        return jnp.mean(jnp.max(hist["force"], axis=-1)) / 1e5

    f = jax.jit(peak)
    grad = np.asarray(jax.jit(jax.grad(peak))(TH0))
    for k, h in enumerate((2e-7, 2e-5)):
        e = np.zeros(2)
        e[k] = h
        fd = (float(f(TH0 + e)) - float(f(TH0 - e))) / (2 * h)
        assert grad[k] == pytest.approx(fd, rel=1e-2), (k, grad, fd)


def test_unsupported_uses_raise(struct):
    law = _law("hertz-trajectory", TH0)
    with pytest.raises(NotImplementedError, match="wheel_disp"):  # raised while tracing
        jax.jit(jax.grad(lambda th: jnp.sum(adj.adjoint_loop(
            _law("hertz-trajectory", th), struct, V, DT, X0, IMPACT, 50)["wheel_disp"]))).lower(
                TH0)
    with pytest.raises(NotImplementedError, match="speed"):
        jax.jit(jax.grad(lambda v: jnp.sum(adj.adjoint_loop(law, struct, v, DT, X0, IMPACT,
                                                            50)["force"]))).lower(V)

    @dataclasses.dataclass(frozen=True)
    class OwnStep(laws.HertzTrajectoryLaw):
        def step(self, *args, **kwargs):
            return super().step(*args, **kwargs)

    with pytest.raises(NotImplementedError, match="pointwise"):
        adj.adjoint_loop(OwnStep(law.c_h, law.s_grid, law.drop, law.flat), struct, V, DT,
                         X0, IMPACT, 50)


@pytest.mark.slow
def test_max_force_model_adjoint_option():
    """max_force_model(adjoint=True): the same forces, the plain reverse-mode gradient."""
    coarse = wf.SimConfig(max_travel_step=1e-3, max_time_step=5e-5)
    ref = _flat(np.asarray(TH0))
    kw = dict(impact_positions=[0.1], config=coarse)
    speeds = np.array([60.0, 120.0]) / 3.6
    plain = fit.max_force_model(speeds, ref, "hertz-trajectory", **kw)
    ours = fit.max_force_model(speeds, ref, "hertz-trajectory", adjoint=True, **kw)
    np.testing.assert_array_equal(np.asarray(jax.jit(lambda f: ours(f))(_flat(TH0))),
                                  np.asarray(jax.jit(lambda f: plain(f))(_flat(TH0))))
    g_plain = jax.jit(jax.grad(lambda th: jnp.sum(plain(_flat(th)))))(TH0)
    _close(jax.jit(jax.grad(lambda th: jnp.sum(ours(_flat(th)))))(TH0), g_plain)


@pytest.mark.slow
def test_fit_reverse_mode_uses_the_adjoint():
    """fit_flat(mode="reverse") on max-force data: its Gauss-Newton Jacobian (jacrev through
    the adjoint, vmapped over the residuals) matches the forward-mode Jacobian."""
    coarse = wf.SimConfig(max_travel_step=1e-3, max_time_step=5e-5)
    speeds = np.array([60.0, 120.0]) / 3.6
    par = fit.parametrisation_for(wf.Flat.rounded(0.9e-3, 0.1), 0.06)
    theta = jnp.asarray(par.from_flat(wf.Flat.rounded(0.9e-3, 0.1)))
    ref = dataclasses.replace(wf.Flat.rounded(0.9e-3, 0.1), extent_bound=0.06)
    kw = dict(impact_positions=[0.1], config=coarse)
    y = jnp.asarray([150e3, 250e3])
    fwd = _objective(fit.max_force_model(speeds, ref, "hertz-trajectory", **kw), par, y,
                         2e5, "forward")
    rev = _objective(fit.max_force_model(speeds, ref, "hertz-trajectory", adjoint=True,
                                             **kw), par, y, 2e5, "reverse")
    (j_f, r_f), (j_r, r_r) = fwd[2](theta), rev[2](theta)
    np.testing.assert_array_equal(np.asarray(r_r), np.asarray(r_f))
    _close(j_r, j_f, 1e-6)
    _close(rev[0](theta)[1], fwd[0](theta)[1], 1e-6)


@pytest.mark.slow
def test_history_model_adjoint_option():
    """history_model(adjoint=True), one run through the batched path: the same forces bit for
    bit, the plain reverse-mode gradient."""
    coarse = wf.SimConfig(max_travel_step=1e-3, max_time_step=5e-5)
    t = np.linspace(-4e-3, 8e-3, 40)
    kw = dict(impact_position=0.2, config=coarse)
    plain = fit.history_model(t, V, _flat(np.asarray(TH0)), "hertz-trajectory", **kw)
    ours = fit.history_model(t, V, _flat(np.asarray(TH0)), "hertz-trajectory", adjoint=True,
                             **kw)
    np.testing.assert_array_equal(np.asarray(jax.jit(lambda f: ours(f))(_flat(TH0))),
                                  np.asarray(jax.jit(lambda f: plain(f))(_flat(TH0))))

    def misfit(model):
        return lambda th: jnp.sum((model(_flat(th)) / 1e5) ** 2)

    _close(jax.jit(jax.grad(misfit(ours)))(TH0), jax.jit(jax.grad(misfit(plain)))(TH0))

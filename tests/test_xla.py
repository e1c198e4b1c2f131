"""wfjax._xla: host arrays reach the device without compiling; the loop's compiler options."""

import logging

import jax
import jax.numpy as jnp
import numpy as np

from wfjax._xla import LOOP_COMPILER_OPTIONS, to_device


def _compiles(caplog, fn) -> list[str]:
    caplog.clear()
    with caplog.at_level(logging.WARNING), jax.log_compiles(True):
        fn()
    return [r.getMessage() for r in caplog.records if "Compiling" in r.getMessage()]


def test_to_device_equals_asarray_and_compiles_nothing(caplog):
    host = np.arange(13 * 17 * 3, dtype=float).reshape(13, 17, 3) / 7.0  # a shape of its own
    assert _compiles(caplog, lambda: jnp.asarray(host[:-1]))  # the check sees a compile
    assert not _compiles(caplog, lambda: to_device(host))
    for x, dtype in ((host, None), (np.float64(2.5), None), (3, float), (np.arange(5), float)):
        got, want = to_device(x, dtype), jnp.asarray(x, dtype)
        assert isinstance(got, jax.Array) and got.dtype == want.dtype
        assert got.weak_type == want.weak_type and np.array_equal(got, want)
    assert to_device(0.5).weak_type  # a Python scalar without dtype stays weakly typed


def test_loop_options_compile_the_same_numbers():
    """The classic emitters (LOOP_COMPILER_OPTIONS) give a modal-style recursion's result to
    rounding: a complex multiply-add scan like the time loop's."""
    def loop(a, b):
        def step(q, f):
            q = a * q + b * f
            return q, jnp.real(jnp.sum(q))
        return jax.lax.scan(step, jnp.zeros_like(a), jnp.linspace(0.0, 1.0, 200))[1]

    a = jnp.exp((-0.01 + 0.3j) * jnp.arange(1, 65))
    b = jnp.ones(64) * (0.5 - 0.1j)
    plain = jax.jit(loop)(a, b)
    classic = jax.jit(loop, compiler_options=LOOP_COMPILER_OPTIONS)(a, b)
    np.testing.assert_allclose(classic, plain, rtol=1e-12, atol=1e-12)


def test_loop_options_go_to_the_cpu_alone(monkeypatch):
    """A GPU refuses the CPU emitter option ("No such compile option"): other backends get
    XLA's own options."""
    from wfjax import _xla

    assert _xla.loop_compiler_options() == LOOP_COMPILER_OPTIONS  # the suite runs on a CPU
    monkeypatch.setattr(_xla.jax, "default_backend", lambda: "gpu")
    assert _xla.loop_compiler_options() is None

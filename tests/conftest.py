"""Test configuration: float64 JAX (wfjax enables x64 on import; make it explicit here).

One CPU device unless the caller chose otherwise: the ``wfjax`` command exposes one device per
core (``cli.expose_cpu_cores``), and which test first initialises JAX's backend must not decide
the device count of the whole session (tests/test_sharding.py runs its own processes).
"""

from wfjax.cli import expose_cpu_cores

expose_cpu_cores(1)  # before anything initialises JAX's backend

import importlib  # noqa: E402

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)


@pytest.fixture(name="no_work")
def _no_work(monkeypatch):
    """Make any simulation fail loudly: a command's errors must come before its work."""
    def boom(*args, **kwargs):
        raise AssertionError("a simulation ran")

    monkeypatch.setattr(importlib.import_module("wfjax.sweeps"), "sweep", boom)
    monkeypatch.setattr(importlib.import_module("wfjax.api"), "simulate", boom)

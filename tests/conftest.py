"""Test configuration: float64 JAX (wfjax enables x64 on import; make it explicit here).

One CPU device unless the caller chose otherwise: the ``wfjax`` command exposes one device per
core (``cli.expose_cpu_cores``), and which test first initialises JAX's backend must not decide
the device count of the whole session (tests/test_sharding.py runs its own processes).
"""

from wfjax.cli import expose_cpu_cores

expose_cpu_cores(1)  # before anything initialises JAX's backend

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

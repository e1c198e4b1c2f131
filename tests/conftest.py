"""Test configuration: float64 JAX (wfjax enables x64 on import; make it explicit here).

One CPU device unless the caller chose otherwise: the ``wfjax`` command exposes one device per
core (``cli.expose_cpu_cores``), and which test first initialises JAX's backend must not decide
the device count of the whole session (tests/test_sharding.py runs its own processes).
"""

import os

if "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                               + " --xla_force_host_platform_device_count=1").strip()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import wfjax  # noqa: E402,F401  (import after the config update)

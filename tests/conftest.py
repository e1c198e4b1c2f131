"""Test configuration: float64 JAX (wfjax enables x64 on import; make it explicit here)."""

import jax

jax.config.update("jax_enable_x64", True)

import wfjax  # noqa: E402,F401  (import after the config update)

"""XLA compiler options of wfjax's time loops and 3D window solvers; host arrays to the device.

``loop_compiler_options()`` goes to the top-level ``jax.jit`` of every program wfjax compiles
around a time loop: :func:`wfjax.simulate`'s, the sweep's, the fits' objectives (JAX refuses
compiler options on a nested jit, so ``run_scan`` and ``run_adjoint``, which users and these
programs call inside their own jits, carry none). On the CPU, XLA's MLIR fusion
emitters spend about twice the CPU time of its classic LLVM IR emitters on the loops' ~170
fusions, for the same run time and results to the last bits of float64 rounding
(``benchmarks/README.md``, issue 20: the default sweep's program 3.9 -> 2.0 CPU-s, the cold
main job ~1.5 s shorter). The option names a CPU code generator, and other backends refuse it
("No such compile option" on a GPU, JAX 0.11.2, 2026-12-04), so it goes to the CPU alone.

``SOLVER_COMPILER_OPTIONS`` goes to the 3D window solvers of the table builds on the CPU
(:func:`wfjax.contact.windows.window_solver`): LLVM's optimisation level 1 instead of 2 and the
classic emitters compile each in ~0.2 CPU-s less (0.85-0.94 against 0.98-1.27 CPU-s) and
solve as fast (1.56-1.58 against 1.57-1.73 ms on a 45 x 50 window); a cold default sweep
compiles three. The time loops gain nothing from level 1 (within noise).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

LOOP_COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False}
SOLVER_COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False,
                           "xla_backend_optimization_level": 1}


def loop_compiler_options() -> dict | None:
    """The time loops' compiler options for JAX's default backend (None: XLA's own)."""
    return cpu_only(LOOP_COMPILER_OPTIONS)


def cpu_only(options: dict) -> dict | None:
    """``options`` when JAX's default backend is the CPU, else None (level 1 is for CPUs)."""
    return options if jax.default_backend() == "cpu" else None


def array_module(a):
    """numpy for a host array (concrete work: no op-by-op compilation per shape), else jnp
    (JAX arrays and tracers)."""
    return np if isinstance(a, np.ndarray) else jnp


def to_device(x, dtype=None):
    """``jnp.asarray(x, dtype)`` without compiling for host values (NumPy arrays and scalars).

    In this JAX ``jnp.asarray`` of a NumPy array compiles a small program per shape and dtype
    (15-35 ms each; a cold ``wfjax sweep`` compiled 20 of them while it built its modal model
    and tables); ``jax.device_put`` copies. A Python scalar keeps ``jnp.asarray``'s weak type
    unless ``dtype`` is given; JAX arrays and tracers go through ``jnp.asarray``.
    """
    if isinstance(x, (np.ndarray, np.generic)) or (dtype is not None
                                                    and isinstance(x, (int, float, complex))):
        return jax.device_put(np.asarray(x, dtype))
    return jnp.asarray(x, dtype)

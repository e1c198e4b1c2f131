"""XLA compiler options of wfjax's compiled time loops.

``LOOP_COMPILER_OPTIONS`` goes to the top-level ``jax.jit`` of every program wfjax compiles
around a time loop: :func:`wfjax.simulate`'s, the sweep's, the fits' objectives (JAX refuses
compiler options on a nested jit, so ``run_scan`` and ``run_adjoint``, which users and these
programs call inside their own jits, carry none). On the CPU, XLA's MLIR fusion
emitters spend about twice the CPU time of its classic LLVM IR emitters on the loops' ~170
fusions, for the same run time and results to the last bits of float64 rounding
(``benchmarks/README.md``, issue 20: the default sweep's program 3.9 -> 2.0 CPU-s, the cold
main job ~1.5 s shorter). The option names a CPU code generator only; other backends ignore it.
The 3D contact solver is left at XLA's default (there the two emitters are equally fast).
"""

from __future__ import annotations

LOOP_COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False}

"""Seconds this process has spent compiling, from ``jax.monitoring`` events.

The benchmarks report compile time apart from run time; they read :func:`compile_seconds`
before and after a call. The listener is registered on import, so compilations before that
are not counted.
"""

from __future__ import annotations

import jax

COMPILE_EVENTS = ("/jax/core/compile/jaxpr_trace_duration",
                  "/jax/core/compile/jaxpr_to_mlir_module_duration",
                  "/jax/core/compile/backend_compile_duration")
_total = {"seconds": 0.0}


def _listener(event: str, duration: float, **_) -> None:
    if event in COMPILE_EVENTS:
        _total["seconds"] += duration


jax.monitoring.register_event_duration_secs_listener(_listener)


def compile_seconds() -> float:
    """Tracing, lowering and XLA compilation time [s] summed since this module was imported."""
    return _total["seconds"]

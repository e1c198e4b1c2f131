"""Independent XLA computations side by side: one host thread per CPU core; LAPACK's threads
for small dense problems."""

from __future__ import annotations

import concurrent.futures
import contextlib
import os
import threading
from collections.abc import Callable, Sequence

_POOL: list[concurrent.futures.ThreadPoolExecutor] = []
_POOL_LOCK = threading.Lock()


def map_per_core(fn: Callable, items: Sequence) -> list:
    """``[fn(item) for item in items]``, run in one thread per CPU core (at most len(items)).

    One XLA CPU computation keeps about one core busy and XLA releases the GIL while it runs,
    so independent builds (3D contact tables, family nodes) finish in about the time of the
    slowest per core. Order them most expensive first.
    """
    workers = max(1, min(len(items), os.cpu_count() or 1))
    with concurrent.futures.ThreadPoolExecutor(workers) as pool:
        return list(pool.map(fn, items))


def core_pool() -> concurrent.futures.ThreadPoolExecutor:
    """The process's pool of one thread per CPU core for small XLA work items.

    Builds that run side by side in their own threads (the sweep's table prefetch) submit
    their items here, so together they keep every core busy whatever their sizes: first in,
    first out. An item may wait only on items submitted before it (those have started).
    """
    with _POOL_LOCK:
        if not _POOL:
            _POOL.append(concurrent.futures.ThreadPoolExecutor(
                max(1, os.cpu_count() or 1), thread_name_prefix="wfjax-core"))
        return _POOL[0]


def in_background(fn: Callable, *args) -> concurrent.futures.Future:
    """``fn(*args)`` in a daemon thread: its result (or exception) in the returned future.

    For work that overlaps other work of the caller (a sweep's 3D tables while its modal
    model builds and its program compiles); a daemon thread never keeps the process alive
    after an error elsewhere.
    """
    future: concurrent.futures.Future = concurrent.futures.Future()

    def run():
        try:
            future.set_result(fn(*args))
        except BaseException as err:  # noqa: BLE001 - handed to the caller through the future
            future.set_exception(err)

    threading.Thread(target=run, daemon=True, name="wfjax-background").start()
    return future


class _Deferred:
    """Work started by :func:`start_deferred`, or by the first :meth:`result`."""

    def __init__(self, fn: Callable, args: tuple):
        self._fn, self._args, self._future = fn, args, None
        self._lock = threading.Lock()

    def start(self) -> concurrent.futures.Future:
        with self._lock:
            if self._future is None:
                self._future = in_background(self._fn, *self._args)
            return self._future

    def result(self):
        return self.start().result()


_DEFERRED: list[_Deferred] = []


def while_compiling(fn: Callable, *args) -> _Deferred:
    """``fn(*args)`` in a daemon thread from when the next program has been traced and XLA
    compiles it (:func:`start_deferred`), or at once when its ``result()`` is asked for first.

    For Python-bound work that would otherwise contend for the GIL with the main thread's
    own Python while that is the critical path: matplotlib's import (0.4 s) beside a cold
    sweep's modal model and trace held them back by 0.1-0.2 s; while XLA compiles, the GIL
    is free.
    """
    deferred = _Deferred(fn, args)
    _DEFERRED.append(deferred)
    return deferred


def start_deferred() -> None:
    """Start the work :func:`while_compiling` deferred (called once a program is traced)."""
    while _DEFERRED:
        _DEFERRED.pop().start()


SMALL_DENSE = 1000  # dense eigenproblems below this order run on one BLAS thread


def dense_threads(n: int):
    """A context for a dense LAPACK solve of order ``n``: one BLAS thread when ``n <
    SMALL_DENSE``, the library's default otherwise.

    With JAX's own thread pools in the process, OpenBLAS's threads cost more than they give
    on the default track's eigenproblems (order 688): its modal model took 0.30-0.32 s on one
    thread against 0.44-0.52 s on two (2-core CPU, idle, 3 runs each), and 5-20x longer on
    two when other jobs load the cores. Larger problems (order 1400: 0.53 s on one thread, 0.32
    s on two) keep the threads. Without ``threadpoolctl`` nothing changes.
    """
    if n >= SMALL_DENSE:
        return contextlib.nullcontext()
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return contextlib.nullcontext()
    return threadpool_limits(1, user_api="blas")

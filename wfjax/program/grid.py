"""A program's runs over a grid on the devices: the plan, the chunks and the devices.

The runs of a group (flats x speeds x positions x realisations) are flattened, sorted by their
step count and cut into chunks sized for the devices (:func:`chunk_width`: from the device's
free memory and the program's bytes per run, capped where more runs no longer raise
throughput). Chunks are dispatched ahead: chunk k + 1 is queued on the devices before chunk
k's results are copied to the host.

Devices: each chunk is sharded over every JAX device (``jax.devices()``) along the flattened
run axis with a one-axis :class:`jax.sharding.Mesh` (axis ``"runs"``); the program's data are
replicated. Every device's batched loop stops at the longest of its own runs, in whole blocks
of :data:`wfjax.loop.run.LOOP_BLOCK` steps, so the lanes of a device's share compute
``lanes x that many`` run-steps however short their own runs are (:func:`run_steps` counts
them). :func:`lane_layout` therefore gives every device a contiguous slice of the sorted runs
(its "group"), not every n-th run of the chunk, and puts the padding (chunks are padded to
one compiled width, a multiple of the device count) at the short end, repeating the
shortest run; padding lanes are dropped afterwards. Runs are independent, so the results
equal the single-device ones. On a CPU,
``XLA_FLAGS=--xla_force_host_platform_device_count=N`` exposes N devices.
Multi-host: call :func:`jax.distributed.initialize` in every process first and run the same
program everywhere; ``jax.devices()`` then spans all hosts and every process receives the
full result (``benchmarks/multihost_example.py``).
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Sequence
from typing import NamedTuple

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from ..loop.run import LOOP_BLOCK
from ..params import Flat, SimConfig
from ..scenario.windows import run_windows

__all__ = ["RunPlan", "plan_runs", "run_chunks", "device_mesh", "replicate", "Progress",
           "chunk_width", "bytes_per_run", "over_realisations", "CHUNK_CAP",
           "ACCELERATOR_CHUNK_CAP", "lane_layout", "run_steps"]

# Runs per device and chunk at most, by platform: throughput no longer rises beyond them.
# CPU: measured (benchmarks/README.md, "Throughput against batch size": 126 runs/s at 64, a
# wider vmap only costs memory); accelerators: thousands of lanes keep a GPU busy.
CHUNK_CAP = {"cpu": 64}


ACCELERATOR_CHUNK_CAP = 8192


CPU_WHEEL_RUNS = 128  # wheels x runs per CPU device and chunk at most (see chunk_width)


MEMORY_FRACTION = 0.5  # of a device's free memory one chunk may take


def device_mesh() -> Mesh:
    """A one-axis mesh ``("runs",)`` over every JAX device (all hosts)."""
    return Mesh(np.array(jax.devices()), ("runs",))


def shard_runs(a: np.ndarray, mesh: Mesh) -> jax.Array:
    """Global array of the [n] per-run values ``a``, split along ``"runs"`` (n % devices == 0).

    Every process holds the same ``a`` and contributes the shards of its own devices.
    """
    sharding = NamedSharding(mesh, PartitionSpec("runs"))
    return jax.make_array_from_callback(a.shape, sharding, lambda idx: a[idx])


def replicate(tree, mesh: Mesh):
    """Array leaves of ``tree`` replicated on every device of ``mesh`` (other leaves unchanged)."""
    sharding = NamedSharding(mesh, PartitionSpec())

    def put(x):
        if not isinstance(x, (jax.Array, np.ndarray)):
            return x
        host = np.asarray(x)
        return jax.make_array_from_callback(host.shape, sharding, lambda idx: host[idx])

    return jax.tree.map(put, tree)


def gather(arrays) -> list[np.ndarray]:
    """Sharded results as host NumPy arrays (an all-gather across processes on multi-host)."""
    if jax.process_count() > 1:
        return [np.asarray(a) for a in multihost_utils.process_allgather(arrays, tiled=True)]
    return [np.asarray(a) for a in arrays]


class Progress:
    """Runs done of ``total`` with an ETA; ``work`` (e.g. run-steps) done and in all, when
    given, paces the ETA (a sweep's chunks of short runs go first)."""

    def __init__(self, total: int, label: str, stream=sys.stderr, enabled: bool = True):
        self.total, self.label, self.stream, self.enabled = total, label, stream, enabled
        self.start = time.perf_counter()
        self.done = 0
        self.work_done, self.work_total = 0.0, None

    def update(self, n: int, work: float | None = None) -> None:
        self.done += n
        self.work_done += n if work is None else work
        if not self.enabled:
            return
        elapsed = time.perf_counter() - self.start
        total = self.total if self.work_total is None else self.work_total
        eta = (elapsed / self.work_done * (total - self.work_done) if self.work_done
               else float("nan"))
        end = "\n" if self.done >= self.total else "\r"
        line = (f"  {self.label}: {self.done}/{self.total} runs, {elapsed:5.1f} s elapsed, "
                f"ETA {eta:5.1f} s")
        print(line.ljust(len(self.label) + 40), end=end, file=self.stream, flush=True)


class RunPlan(NamedTuple):
    """A group's runs, flattened over (flat, speed, position, realisation), and their chunks.

    ``columns``: [n] per-run arrays in the order of the program's run arguments (flat index,
    speed [m/s], dt [s], x_start [m], impact position [m], run-in steps, end step,
    realisation), the runs sorted by their step count (``order``: where each one's results
    go); ``step``: real runs per chunk at most (:func:`chunk_layout`); ``width``: the compiled
    chunk width (a multiple of ``n_devices``); ``lanes`` [n_chunks * width]: the run (index
    into ``columns``) of every lane, chunk k = lanes[k * width:(k + 1) * width], device d its
    d-th of ``n_devices`` equal slices; ``real`` [n_chunks * width]: False on padding lanes
    (which repeat run 0, the shortest); ``shape`` (n_flats, n_speeds, n_positions, n_real).
    """

    n_steps: int
    columns: tuple
    step: int
    width: int
    shape: tuple
    order: np.ndarray  # [n] each planned run's index in the (flat, speed, position,
    # realisation) order of the results
    lanes: np.ndarray
    real: np.ndarray
    n_devices: int

    @property
    def n_chunks(self) -> int:
        """Chunks of ``width`` lanes."""
        return self.lanes.size // self.width

    def chunk_lanes(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(runs [width] of chunk ``k``'s lanes, which of them are real [width] bool)."""
        sl = slice(k * self.width, (k + 1) * self.width)
        return self.lanes[sl], self.real[sl]

    def chunk_runs(self, k: int) -> int:
        """Real runs in chunk ``k`` (its lanes less the padding)."""
        return int(self.chunk_lanes(k)[1].sum())


_END_STEPS = 6  # the end-step column among RunPlan.columns (the order of core.Run)


def plan_runs(window_flats: Sequence[Flat], v, pos, struct, config: SimConfig, mesh: Mesh,
               chunk_size: int | None, n_real: int = 1) -> RunPlan:
    """The runs of one group: flat i runs at every speed in the window of ``window_flats[i]``
    there, with the step count and time step :func:`wfjax.simulate` takes
    (:func:`run_windows`); the program's step count is the largest, and the steps after a
    run's own window are not counted in its summaries. The runs are sorted by their step
    count and laid out on the chunks' lanes by :func:`lane_layout` (each device's loop stops
    at its own longest run); chunks: ``chunk_size`` runs, default from the devices' memory
    (:func:`chunk_width`)."""
    n_flats = len(window_flats)
    windows = [run_windows(f, v, config) for f in window_flats]
    n_fv, dt_fv, s0_fv, run_in_fv = (np.stack([w[i] for w in windows]) for i in range(4))
    n_steps = int(n_fv.max())
    n_devices = mesh.devices.size
    if chunk_size is None:
        n_modes = int(struct.track.poles.shape[0])
        n_wheels = 1 if struct.offsets is None else int(struct.offsets.shape[0])
        per_device = chunk_width(n_steps, n_modes, config.precision, n_wheels=n_wheels)
        if jax.process_count() > 1:  # every process must compile and run the same chunks
            per_device = int(np.min(multihost_utils.process_allgather(np.int32(per_device))))
        chunk_size = n_devices * per_device
    ff, jj, kk, rr = (a.ravel() for a in np.meshgrid(np.arange(n_flats), np.arange(v.size),
                                                     np.arange(pos.size), np.arange(n_real),
                                                     indexing="ij"))
    pp, s_start = pos[kk], s0_fv[ff, jj]
    columns = (ff, v[jj], dt_fv[ff, jj], pp + s_start, pp, run_in_fv[ff, jj], n_fv[ff, jj], rr)
    step, width = chunk_layout(ff.size, chunk_size, n_devices)
    order = np.argsort(n_fv[ff, jj], kind="stable")
    ends = n_fv[ff, jj][order]
    lanes, real = lane_layout(ends, -(-ff.size // step), width, n_devices)
    return RunPlan(n_steps, tuple(a[order] for a in columns), step, width,
                   (n_flats, v.size, pos.size, n_real), order, lanes, real, n_devices)


def loop_steps(end) -> np.ndarray:
    """Steps a loop stopping at ``end`` (its longest run's step count) computes: the
    ``end - 1`` steps after the initial state, rounded up to whole blocks of
    :data:`~wfjax.loop.run.LOOP_BLOCK` (128) steps (``time_loop(n_run=...)``)."""
    return -(-(np.asarray(end) - 1) // LOOP_BLOCK) * LOOP_BLOCK


def lane_layout(ends: np.ndarray, n_chunks: int, width: int,
                n_devices: int) -> tuple[np.ndarray, np.ndarray]:
    """(lanes [n_chunks * width]: the run of every lane, real [n_chunks * width] bool) for
    runs of sorted step counts ``ends`` [n] (ascending).

    A device's share of a chunk (``width / n_devices`` lanes) computes its lanes times its
    longest run's :func:`loop_steps`, so it should hold runs of like step counts: the sorted
    runs, preceded by the padding (``n_chunks * width - n`` lanes repeating run 0, the
    shortest), are cut into ``n_chunks * n_devices`` contiguous groups, chunk k takes groups
    k * n_devices ... (k + 1) * n_devices - 1, and within a chunk the costliest group goes to
    the device with the least work so far. The default sweep (580 runs, 5 chunks of 2 x 58
    lanes): 1.76 M run-steps computed for 1.66 M needed, against 1.83 M when every device
    took every second run of its chunk (each spanning the chunk's whole range of step
    counts); the Fig. 8 set 5.57 M (5.67 M) for 5.39 M.

    What it saves is CPU time, not a chunk's wall time on idle cores: JAX's CPU client runs
    one sharded chunk at a time (the next dispatch waits for the previous chunk on every
    device, measured with jax 0.10.2), so a chunk lasts as long as its slowest device's
    share, whose longest run is the chunk's either way. Where the cores are shared (another
    process, or fewer cores than devices) the CPU time is the wall time.
    """
    share = width // n_devices
    pad = n_chunks * width - ends.size
    virtual = np.concatenate([np.zeros(pad, int), np.arange(ends.size)])
    real = np.concatenate([np.zeros(pad, bool), np.ones(ends.size, bool)])
    groups = virtual.reshape(n_chunks * n_devices, share)
    cost = share * loop_steps(ends[groups].max(axis=1))
    load, slots = np.zeros(n_devices), []
    for k in range(n_chunks):
        g = k * n_devices + np.argsort(-cost[k * n_devices:(k + 1) * n_devices], kind="stable")
        devices = np.argsort(load, kind="stable")  # the least loaded first
        load[devices] += cost[g]
        placed = np.empty(n_devices, int)
        placed[devices] = g
        slots.append(placed)
    slots = np.concatenate(slots)
    return groups[slots].ravel(), real.reshape(groups.shape)[slots].ravel()


def run_steps(runs: RunPlan) -> tuple[int, int]:
    """(run-steps needed: every run's own ``end - 1`` steps, run-steps computed: every
    device share's lanes x its longest run's :func:`loop_steps`) of a plan."""
    ends = runs.columns[_END_STEPS]
    share = runs.width // runs.n_devices
    longest = ends[runs.lanes].reshape(-1, share).max(axis=1)
    return int(np.sum(ends - 1)), int(share * loop_steps(longest).sum())


def chunk(runs: RunPlan, k: int, mesh: Mesh) -> tuple[int, list]:
    """(real runs in chunk ``k``, its sharded arguments: ``width`` lanes of every column)."""
    lanes, _ = runs.chunk_lanes(k)
    return runs.chunk_runs(k), [shard_runs(a[lanes], mesh) for a in runs.columns]


def run_chunks(program, data, runs: RunPlan, mesh: Mesh, bar: Progress) -> dict[str, np.ndarray]:
    """Per-run results by name, [n_flats, n_speeds, n_positions, n_real, ...], of the runs
    ``runs`` of one group (the realisation axis: roughness or support realisations, 1
    without): ``program(data, *run_columns)`` (a compiled, sharded batch of runs) on every
    chunk, ``bar`` counting the runs.

    Every chunk is dispatched before the previous one is collected (one chunk in flight)."""
    n = runs.columns[0].size
    share = runs.width // runs.n_devices
    ends = runs.columns[_END_STEPS]  # a chunk's work: its devices' lanes x longest runs
    work = [float(share * loop_steps(ends[runs.chunk_lanes(k)[0]].reshape(-1, share)
                                     .max(axis=1)).sum()) for k in range(runs.n_chunks)]
    bar.work_total = float(sum(work))
    planned: dict[str, np.ndarray] = {}

    def collect(batch, k):
        lanes, real = runs.chunk_lanes(k)
        keys = sorted(batch)
        for key, b in zip(keys, gather([batch[key] for key in keys]), strict=True):
            out = planned.setdefault(key, np.empty((n,) + b.shape[1:], b.dtype))
            out[lanes[real]] = b[real]
        bar.update(int(real.sum()), work[k])

    in_flight = None
    for k in range(runs.n_chunks):
        batch = program(data, *chunk(runs, k, mesh)[1])
        if in_flight is not None:
            collect(*in_flight)
        in_flight = (batch, k)
    collect(*in_flight)
    return {k: unsorted(a, runs.order).reshape(runs.shape + a.shape[1:])
            for k, a in planned.items()}


def unsorted(planned: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Per-run results [n, ...] in planned order back in the results' order."""
    out = np.empty_like(planned)
    out[order] = planned
    return out


_MIN_KEYS = ("min", "w_min", "s_min")


def over_realisations(key: str, col: np.ndarray) -> np.ndarray:
    """A per-run summary [n_flats, n_speeds, n_positions, R, ...] reduced over the
    realisations: min for minima, max for the rest (maxima, peaks, loss-of-contact flags and
    durations, residuals)."""
    return np.min(col, axis=3) if key in _MIN_KEYS else np.max(col, axis=3)


def bytes_per_run(n_steps: int, n_modes: int, precision: str = "float64",
                  n_wheels: int = 1) -> int:
    """Device memory [bytes] one run of the batched time loop needs (an upper estimate).

    24 complex vectors of ``n_modes`` (carry, propagated state, shapes at the contact and
    their products) and 2 reals per step. Fitted to the compiled program's
    ``memory_analysis()`` on CPU (temporaries at 16 and 64 runs, 599 modes): float64
    215 / 262 KB per run at 1000 / 4000 steps (estimate 246 / 294 KB), float32 74 / 77 KB
    (estimate 123 / 147 KB); the width-independent rest (~11 MB: the structure's modes) is
    left to ``MEMORY_FRACTION``. Every further wheel of a vehicle adds its shapes, their
    products and the gathered nodal rows (8 complex vectors) and its outputs per step.
    """
    real = 4 if precision == "float32" else 8  # "auto" sized as float64 (the direct 3D mode)
    return real * (2 * n_steps * n_wheels + (24 + 8 * (n_wheels - 1)) * 2 * n_modes)


def chunk_width(n_steps: int, n_modes: int, precision: str = "float64",
                device: jax.Device | None = None, n_wheels: int = 1) -> int:
    """Runs per device and chunk: as many as ``MEMORY_FRACTION`` of the device's free memory
    holds (:func:`bytes_per_run`), at most the platform's throughput cap (``CHUNK_CAP``: 64
    on CPU; ``ACCELERATOR_CHUNK_CAP`` on GPUs/TPUs) and at least 1. On a CPU the cap counts
    wheel-runs (``CPU_WHEEL_RUNS`` = 128 per device): a step's working set (every wheel's
    nodal mode-shape rows) grows with the wheels, and beyond the caches a wider batch is
    slower per run (measured: 8 wheels 5.98x the one-wheel time per run at 16 runs, 6.4x at 8,
    10.7x at 64).

    ``device``: default the first local device. Free memory: ``device.memory_stats()``
    (``bytes_limit - bytes_in_use``) where the backend
    reports it (GPU, TPU); else the host's available memory over its local device count
    (CPU devices share the host's memory).
    """
    device = device or jax.local_devices()[0]  # this process's (another host's: no stats)
    stats = device.memory_stats() or {}
    if "bytes_limit" in stats:
        free = stats["bytes_limit"] - stats.get("bytes_in_use", 0)
    else:
        free = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES") / max(
            1, jax.local_device_count())
    cap = CHUNK_CAP.get(device.platform, ACCELERATOR_CHUNK_CAP)
    if device.platform == "cpu":
        cap = min(cap, max(1, CPU_WHEEL_RUNS // n_wheels))
    fits = int(MEMORY_FRACTION * free // bytes_per_run(n_steps, n_modes, precision, n_wheels))
    return max(1, min(cap, fits))


def chunk_layout(n_runs: int, chunk_size: int, n_devices: int) -> tuple[int, int]:
    """(runs per chunk, compiled chunk width) for ``n_runs`` runs.

    One compiled shape serves every chunk, so the last chunk is padded to the width; the runs
    are spread evenly over the fewest chunks of at most ``chunk_size`` (80 runs at 64 become
    2 x 40, not 64 + 16 padded to 64), and the width is a multiple of the device count.
    """
    n_chunks = -(-n_runs // chunk_size)
    step = -(-n_runs // n_chunks)
    return step, -(-step // n_devices) * n_devices


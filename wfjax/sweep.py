"""Batched simulations: speeds x impact positions (x flats), ``vmap``-ed and chunked.

All runs of one flat share one compiled program: every speed uses the same number of steps
(the largest any speed needs) with its own time step, so the batch is rectangular. The batch
is cut into chunks (memory) and progress with an ETA is printed per chunk.

Devices: each chunk is sharded over every JAX device (``jax.devices()``) along the flattened
run axis with a one-axis :class:`jax.sharding.Mesh` (axis ``"runs"``) and a
:class:`jax.sharding.NamedSharding`; the model parameters are replicated. A chunk is padded to
a multiple of the device count (padding repeats the last run and is dropped afterwards).
Runs are independent, so the results equal the single-device ones. On a CPU,
``XLA_FLAGS=--xla_force_host_platform_device_count=N`` exposes N devices. Multi-host: call
:func:`jax.distributed.initialize` in every process before the sweep and run the same sweep
everywhere; ``jax.devices()`` then spans all hosts and every process receives the full result
(``benchmarks/multihost_example.py``).
"""

from __future__ import annotations

import csv
import functools
import io
import json
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from .interaction import (
    RUN_IN_TIME,
    contact_spec,
    n_steps_for,
    run_scan,
    simulation_window,
    structure,
    summarise,
)
from .params import Flat, Material, SimConfig, Track, Wheel

__all__ = ["SweepResult", "sweep", "impact_positions_grid"]


class SweepResult(NamedTuple):
    """Summary values of a sweep; arrays shaped [n_flats, n_speeds, n_positions].

    Attributes:
        speeds: [n_speeds] train speeds [m/s].
        impact_positions: [n_positions] impact positions within the bay [m].
        max_force, min_force: contact force extremes after the run-in [N].
        loss_of_contact: bool, F = 0 occurred.
        loss_of_contact_duration: time with F = 0 [s].
        max_residual: largest per-step contact-equation residual [m] (solver diagnostic).
        flats: labels of the flats (e.g. ``"rounded d=0.90mm l=100.0mm"``).
        contact: the contact model.
    """

    speeds: Any
    impact_positions: Any
    max_force: Any
    min_force: Any
    loss_of_contact: Any
    loss_of_contact_duration: Any
    max_residual: Any
    flats: tuple
    contact: str

    def envelope(self) -> dict[str, np.ndarray]:
        """Max over positions of max_force, min over positions of min_force: [n_flats, n_speeds]."""
        return {
            "max_force": np.max(self.max_force, axis=-1),
            "min_force": np.min(self.min_force, axis=-1),
            "loss_of_contact": np.any(self.loss_of_contact, axis=-1),
        }

    def to_csv(self) -> str:
        """One row per (flat, speed, position); forces in kN, speeds in km/h."""
        buf = io.StringIO()
        w = csv.writer(buf)
        w.writerow(["flat", "contact", "speed_kmh", "impact_position_mm", "max_force_kN",
                    "min_force_kN", "loss_of_contact", "loss_of_contact_ms"])
        for i, label in enumerate(self.flats):
            for j, v in enumerate(np.asarray(self.speeds)):
                for k, p in enumerate(np.asarray(self.impact_positions)):
                    w.writerow([label, self.contact, f"{v * 3.6:.6g}", f"{p * 1e3:.6g}",
                                f"{self.max_force[i, j, k] / 1e3:.6f}",
                                f"{self.min_force[i, j, k] / 1e3:.6f}",
                                int(self.loss_of_contact[i, j, k]),
                                f"{self.loss_of_contact_duration[i, j, k] * 1e3:.6g}"])
        return buf.getvalue()

    def save_npz(self, path) -> None:
        """Save every array and label to ``path`` (.npz), atomically."""
        path = Path(path)
        tmp = path.with_name(f".{path.name}.tmp.npz")
        arrays = {k: np.asarray(getattr(self, k)) for k in self._fields
                  if k not in ("flats", "contact")}
        np.savez(tmp, flats=np.array(self.flats), contact=np.array(self.contact), **arrays)
        tmp.replace(path)

    @classmethod
    def load_npz(cls, path) -> SweepResult:
        """Load a result written by :meth:`save_npz`."""
        with np.load(path) as data:
            fields = {k: data[k] for k in cls._fields if k not in ("flats", "contact")}
            return cls(flats=tuple(str(s) for s in data["flats"]),
                       contact=str(data["contact"]), **fields)

    def summary(self) -> dict:
        """JSON-ready summary per flat (kN, km/h)."""
        env = self.envelope()
        out = {"contact": self.contact, "flats": {}}
        for i, label in enumerate(self.flats):
            lost = np.asarray(self.speeds)[env["loss_of_contact"][i]] * 3.6
            j = int(np.argmax(env["max_force"][i]))
            out["flats"][label] = {
                "peak_max_force_kN": float(env["max_force"][i, j]) / 1e3,
                "at_speed_kmh": float(self.speeds[j]) * 3.6,
                "first_loss_of_contact_kmh": float(lost.min()) if lost.size else None,
                "max_spread_over_positions_percent": float(np.max(
                    np.ptp(self.max_force[i], axis=-1) / np.min(self.max_force[i], axis=-1)
                )) * 100,
            }
        return out

    def to_json(self) -> str:
        """:meth:`summary` as JSON text."""
        return json.dumps(self.summary(), indent=2)


def impact_positions_grid(n: int, sleeper_spacing: float = 0.65) -> np.ndarray:
    """``n`` impact positions [m] evenly covering one bay: (k + 0.5) L_S / n."""
    if int(n) != n or n < 1:
        raise ValueError(f"impact_positions must be a positive integer or an array, got {n!r}")
    return (np.arange(int(n)) + 0.5) * sleeper_spacing / int(n)


def flat_label(flat: Flat) -> str:
    """A short human label of a flat (mm)."""
    d = float(flat.depth) * 1e3
    if flat.kind == "rounded":
        return f"rounded d={d:.2f}mm l={float(flat.length) * 1e3:.1f}mm"
    if flat.kind == "new":
        return f"new d={d:.2f}mm"
    return f"{flat.kind} d={d:.2f}mm"


def _reduce(spec_kind, n_steps, max_iter, params, struct, speed, dt, x_start, impact_position,
            run_in_steps):
    hist = run_scan(spec_kind, params, struct, speed, dt, x_start, impact_position, n_steps,
                    max_iter)
    res = summarise(hist, speed, impact_position, dt, run_in_steps)
    return (res.max_force, res.min_force, res.loss_of_contact, res.loss_of_contact_duration,
            jnp.max(res.residual))


@functools.cache
def _batched(mesh: Mesh, spec_kind: str, n_steps: int, max_iter: int):
    """Compiled (params, struct, speed, dt, x_start, impact_position, run_in) -> summaries.

    ``shard_map`` gives every device its own ``vmap``-ed loop over its runs: the batched
    Newton ``while_loop`` then stops on the device's own runs, with no cross-device reduction
    of its condition at every step (what a plain ``jit`` over sharded inputs would compile).
    """
    def local(params, struct, *runs):
        return jax.vmap(functools.partial(_reduce, spec_kind, n_steps, max_iter, params,
                                          struct))(*runs)

    by_run = PartitionSpec("runs")
    return jax.jit(jax.shard_map(local, mesh=mesh, out_specs=by_run, check_vma=False,
                                 in_specs=(PartitionSpec(), PartitionSpec()) + (by_run,) * 5))


def _device_mesh() -> Mesh:
    """A one-axis mesh ``("runs",)`` over every JAX device (all hosts)."""
    return Mesh(np.array(jax.devices()), ("runs",))


def _shard_runs(a: np.ndarray, mesh: Mesh) -> jax.Array:
    """Global array of the [n] per-run values ``a``, split along ``"runs"`` (n % devices == 0).

    Every process holds the same ``a`` and contributes the shards of its own devices.
    """
    sharding = NamedSharding(mesh, PartitionSpec("runs"))
    return jax.make_array_from_callback(a.shape, sharding, lambda idx: a[idx])


def _replicate(tree, mesh: Mesh):
    """Array leaves of ``tree`` replicated on every device of ``mesh`` (other leaves unchanged)."""
    sharding = NamedSharding(mesh, PartitionSpec())

    def put(x):
        if not isinstance(x, (jax.Array, np.ndarray)):
            return x
        host = np.asarray(x)
        return jax.make_array_from_callback(host.shape, sharding, lambda idx: host[idx])

    return jax.tree.map(put, tree)


def _gather(arrays) -> list[np.ndarray]:
    """Sharded results as host NumPy arrays (an all-gather across processes on multi-host)."""
    if jax.process_count() > 1:
        return [np.asarray(a) for a in multihost_utils.process_allgather(arrays, tiled=True)]
    return [np.asarray(a) for a in arrays]


class _Progress:
    def __init__(self, total: int, label: str, stream=sys.stderr, enabled: bool = True):
        self.total, self.label, self.stream, self.enabled = total, label, stream, enabled
        self.start = time.perf_counter()
        self.done = 0

    def update(self, n: int) -> None:
        self.done += n
        if not self.enabled:
            return
        elapsed = time.perf_counter() - self.start
        eta = elapsed / self.done * (self.total - self.done) if self.done else float("nan")
        end = "\n" if self.done >= self.total else "\r"
        line = (f"  {self.label}: {self.done}/{self.total} runs, {elapsed:5.1f} s elapsed, "
                f"ETA {eta:5.1f} s")
        print(line.ljust(len(self.label) + 40), end=end, file=self.stream, flush=True)


def _check_speeds(speeds) -> np.ndarray:
    v = np.atleast_1d(np.asarray(speeds, dtype=float))
    if v.ndim != 1 or v.size == 0 or not np.all(np.isfinite(v)) or np.any(v <= 0) or np.any(
            v > 150):
        raise ValueError(f"speeds must be a non-empty 1-D array in (0, 150] m/s, got {speeds!r}")
    return v


def sweep(flats: Flat | Sequence[Flat], speeds, impact_positions=10, contact: str = "3d",
          wheel: Wheel | None = None, track: Track | None = None,
          material: Material | None = None, config: SimConfig | None = None,
          chunk_size: int = 64, progress: bool = True, cache_dir=None) -> SweepResult:
    """Max/min contact force for every flat x speed x impact position.

    Args:
        flats: one :class:`Flat` or a sequence of them.
        speeds: [n_speeds] train speeds [m/s].
        impact_positions: number of positions evenly covering one bay
            (:func:`impact_positions_grid`) or an array of positions [m] in [0, L_S).
        contact: ``"3d"``, ``"2d"``, ``"hertz-trajectory"`` or ``"hertz-profile"``.
        wheel, track, material, config: model parameters (defaults as in :func:`simulate`).
        chunk_size: simulations per vmapped batch (memory bound), over all devices; each chunk
            is padded to a multiple of the device count and sharded across the devices.
        progress: print progress with ETA to stderr.

    Returns:
        :class:`SweepResult` with arrays shaped [n_flats, n_speeds, n_positions].
    """
    wheel = wheel or Wheel()
    track = track or Track()
    material = material or Material()
    config = config or SimConfig()
    flat_list = [flats] if isinstance(flats, Flat) else list(flats)
    if not flat_list:
        raise ValueError("flats must contain at least one Flat")
    v = _check_speeds(speeds)
    spacing = float(track.sleeper_spacing)
    if np.ndim(impact_positions) == 0:
        pos = impact_positions_grid(impact_positions, spacing)
    else:
        pos = np.asarray(impact_positions, dtype=float)
        if pos.ndim != 1 or np.any(pos < 0) or np.any(pos >= spacing) or not np.all(
                np.isfinite(pos)):
            raise ValueError(f"impact_positions must lie in [0, {spacing}) m, got {pos!r}")
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be >= 1, got {chunk_size!r}")
    mesh = _device_mesh()
    n_dev = mesh.devices.size
    struct = _replicate(structure(wheel, track, config, cache_dir), mesh)
    shape = (len(flat_list), v.size, pos.size)
    out = {k: np.zeros(shape) for k in ("max", "min", "lost", "lost_t", "res")}
    for i, flat in enumerate(flat_list):
        if progress:  # the 3D table build takes seconds to a minute on a cold cache
            print(f"  {flat_label(flat)}: preparing the {contact} contact law ...", end="\r",
                  file=sys.stderr, flush=True)
        spec = contact_spec(contact, flat, wheel, track, material, config, cache_dir)
        spec_params = _replicate(spec.params, mesh)
        n_steps = max(n_steps_for(flat, float(s), config)[0] for s in v)
        vv, pp = (a.ravel() for a in np.meshgrid(v, pos, indexing="ij"))
        s_start = np.array([simulation_window(flat, float(s), config)[0] for s in vv])
        s_end = np.array([simulation_window(flat, float(s), config)[1] for s in vv])
        dt = (s_end - s_start) / vv / (n_steps - 1)
        run_in = np.floor(0.5 * RUN_IN_TIME / dt).astype(int)
        bar = _Progress(vv.size, flat_label(flat), enabled=progress)
        results = []
        step, width = _chunk_layout(vv.size, chunk_size, n_dev)
        for lo in range(0, vv.size, step):
            sl = slice(lo, lo + step)
            n = vv[sl].size

            def padded(a, pad=width - n):
                return _shard_runs(np.concatenate([a, np.repeat(a[-1:], pad)]), mesh)

            program = _batched(mesh, spec.kind, n_steps, config.newton_iterations)
            batch = program(spec_params, struct, padded(vv[sl]), padded(dt[sl]),
                            padded(pp[sl] + s_start[sl]), padded(pp[sl]), padded(run_in[sl]))
            results.append([b[:n] for b in _gather(batch)])
            bar.update(n)
        cols = [np.concatenate(c).reshape(v.size, pos.size) for c in zip(*results, strict=True)]
        for key, col in zip(("max", "min", "lost", "lost_t", "res"), cols, strict=True):
            out[key][i] = col
    return SweepResult(
        speeds=v, impact_positions=pos, max_force=out["max"], min_force=out["min"],
        loss_of_contact=out["lost"].astype(bool), loss_of_contact_duration=out["lost_t"],
        max_residual=out["res"], flats=tuple(flat_label(f) for f in flat_list), contact=contact,
    )


def _chunk_layout(n_runs: int, chunk_size: int, n_devices: int) -> tuple[int, int]:
    """(runs per chunk, compiled chunk width) for ``n_runs`` runs.

    One compiled shape serves every chunk, so the last chunk is padded to the width; the runs
    are spread evenly over the fewest chunks of at most ``chunk_size`` (80 runs at 64 become
    2 x 40, not 64 + 16 padded to 64), and the width is a multiple of the device count.
    """
    n_chunks = -(-n_runs // chunk_size)
    step = -(-n_runs // n_chunks)
    return step, -(-step // n_devices) * n_devices


def loss_of_contact_speed(result: SweepResult, flat_index: int = 0) -> float:
    """Lowest speed [m/s] of the sweep with loss of contact at any position (nan if none)."""
    lost = np.any(result.loss_of_contact[flat_index], axis=-1)
    return float(np.asarray(result.speeds)[lost].min()) if lost.any() else math.nan

"""The chunks' lanes (wfjax.program.grid.lane_layout): every run once, padding at the short end,
each device's share of like step counts, fewer run-steps computed, results in their order."""

from __future__ import annotations

import numpy as np
import pytest

from wfjax.program import grid


def _ends(n: int, seed: int = 0) -> np.ndarray:
    """[n] sorted step counts spread like a sweep's (2100-4300 steps, repeated 10 times)."""
    rng = np.random.default_rng(seed)
    return np.sort(np.repeat(rng.integers(2100, 4300, -(-n // 10)), 10)[:n])


def _plan(n: int, chunk_size: int, n_devices: int) -> grid.RunPlan:
    ends = _ends(n)
    step, width = grid.chunk_layout(n, chunk_size, n_devices)
    lanes, real = grid.lane_layout(ends, -(-n // step), width, n_devices)
    order = np.random.default_rng(1).permutation(n)  # planned run i is results run order[i]
    columns = (np.zeros(n, int), order.astype(float), np.zeros(n), np.zeros(n), np.zeros(n),
               np.zeros(n, int), ends, np.zeros(n, int))
    return grid.RunPlan(int(ends.max()), columns, step, width, (1, n, 1, 1), order, lanes,
                        real, n_devices)


@pytest.mark.parametrize(("n", "chunk_size", "n_devices"),
                         [(580, 128, 2), (1856, 128, 2), (83, 16, 4), (5, 64, 2), (7, 2, 1),
                          (10, 64, 8)])
def test_every_run_once_padding_at_the_short_end(n, chunk_size, n_devices):
    runs = _plan(n, chunk_size, n_devices)
    assert runs.lanes.size == runs.n_chunks * runs.width and runs.width % n_devices == 0
    np.testing.assert_array_equal(np.sort(runs.lanes[runs.real]), np.arange(n))
    assert np.all(runs.lanes[~runs.real] == 0)  # padding repeats the shortest run
    share = runs.width // n_devices
    groups = runs.lanes.reshape(-1, share)
    real = runs.real.reshape(-1, share)
    for g, r in zip(groups, real, strict=True):  # a device's share: a contiguous slice
        assert np.all(np.diff(g[r]) == 1)
    assert sum(runs.chunk_runs(k) for k in range(runs.n_chunks)) == n


def test_fewer_run_steps_than_dealing_every_chunk():
    """The default sweep's shape: 580 runs, 5 chunks of 2 x 58 lanes."""
    runs = _plan(580, 128, 2)
    needed, computed = grid.run_steps(runs)
    ends = runs.columns[6]
    dealt = sum(58 * int(grid.loop_steps(ends[lo:lo + 116][d::2].max()))
                for lo in range(0, 580, 116) for d in range(2))
    assert needed == int(np.sum(ends - 1)) < computed < dealt
    load = [58 * grid.loop_steps(ends[runs.lanes].reshape(-1, 58).max(axis=1))[d::2].sum()
            for d in range(2)]
    assert abs(load[0] - load[1]) < 0.05 * sum(load)  # the devices' work stays balanced


def test_run_chunks_returns_every_run_in_its_place():
    """Results come back in the results' order, padding dropped (one real device, the plan's
    lanes laid out for three)."""
    runs = _plan(83, 16, 3)
    mesh = grid.device_mesh()
    calls = []

    def program(data, *columns):
        calls.append(np.asarray(columns[6]).size)
        return {"speed": columns[1], "end": columns[6]}

    out = grid.run_chunks(program, None, runs, mesh, grid.Progress(83, "t", enabled=False))
    assert calls == [runs.width] * runs.n_chunks  # one compiled width for every chunk
    np.testing.assert_array_equal(out["speed"].ravel(), np.arange(83.0))
    back = grid.unsorted(runs.columns[6], runs.order)
    np.testing.assert_array_equal(out["end"].ravel(), back)

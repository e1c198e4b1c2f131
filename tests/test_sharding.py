"""Sharded sweeps: two forced host devices give the single-device result."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

SCRIPT = textwrap.dedent("""
    import sys
    import jax
    import numpy as np
    import wfjax as wf

    assert len(jax.devices()) == int(sys.argv[2]), jax.devices()
    flat = wf.Flat.rounded(depth=0.9e-3, length=0.1)
    f64 = wf.SimConfig(precision="float64")  # equal to 1e-12 across devices: the float64 loop
    out = []
    for chunk in (64, 4):  # one chunk of 6 runs; 3 + 3 runs (padded to 4 + 4 on 2 devices)
        sw = wf.sweep(flat, np.array([50.0, 100.0]) / 3.6, impact_positions=3,
                      contact="hertz-profile", progress=False, chunk_size=chunk, config=f64)
        out.append(np.stack([sw.max_force, sw.min_force, sw.loss_of_contact_duration,
                             sw.loss_of_contact]))
    np.save(sys.argv[1], np.stack(out))
    from wfjax.scenario.sensors import Detector
    sw = wf.sweep(flat, np.array([50.0, 100.0]) / 3.6, impact_positions=3,
                  contact="hertz-profile", progress=False, chunk_size=4, sensors=[0.1, 0.6],
                  sensor_quantities=("shear", "seat_force"),
                  detector=Detector(n_bays=1, first_bay=0), config=f64)
    np.save(sys.argv[1][:-4] + "_sensors.npy",
            np.concatenate([sw.sensor_max.ravel(), sw.sensor_min.ravel(),
                            sw.detector_peak.ravel()]))
""")


def _start(tmp_path, n_devices: int):
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={n_devices}"
    env["JAX_PLATFORMS"] = "cpu"
    path = tmp_path / f"dev{n_devices}.npy"
    proc = subprocess.Popen([sys.executable, "-c", SCRIPT, str(path), str(n_devices)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return proc, path


@pytest.mark.slow
def test_two_devices_equal_one(tmp_path):
    runs = [_start(tmp_path, n) for n in (1, 2)]
    results = []
    for proc, path in runs:
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err[-2000:]
        results.append(np.load(path))
    one, two = results
    assert one.shape == (2, 4, 1, 2, 3)
    assert np.all(np.isfinite(one)) and np.all(one[:, 0] > 1e5)  # max forces ~ 190-220 kN
    np.testing.assert_allclose(two, one, rtol=1e-12, atol=1e-12 * np.max(one[:, 0]))
    np.testing.assert_allclose(one[1], one[0], rtol=1e-12)  # chunking does not matter
    # sensors and the detector shard like the contact force
    s1, s2 = (np.load(path.with_name(path.stem + "_sensors.npy")) for _, path in runs)
    assert s1.shape == (2 * 6 * 2 * 2 + 6,) and np.all(np.isfinite(s1))
    np.testing.assert_allclose(s2, s1, rtol=1e-12, atol=1e-9)


def test_cli_exposes_one_device_per_core_unless_told(monkeypatch):
    from wfjax.cli import expose_cpu_cores

    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_to=/tmp/x")
    expose_cpu_cores()
    assert os.environ["XLA_FLAGS"] == (
        f"--xla_dump_to=/tmp/x --xla_force_host_platform_device_count={os.cpu_count()}")
    monkeypatch.setenv("XLA_FLAGS", "")
    expose_cpu_cores(1)
    assert os.environ["XLA_FLAGS"] == "--xla_force_host_platform_device_count=1"
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=3")
    expose_cpu_cores()
    assert os.environ["XLA_FLAGS"] == "--xla_force_host_platform_device_count=3"


def test_in_background_hands_back_the_result_or_the_error():
    """The sweep's table builds run through _parallel.in_background: the future holds the
    result, or the exception raised in the thread (never lost), from a daemon thread."""
    import threading

    from wfjax._parallel import in_background

    seen = {}

    def work(x):
        seen["daemon"] = threading.current_thread().daemon
        return 2 * x

    assert in_background(work, 21).result(timeout=10) == 42
    assert seen["daemon"] is True

    def fail():
        raise ValueError("table build failed")

    with pytest.raises(ValueError, match="table build failed"):
        in_background(fail).result(timeout=10)


def test_while_compiling_waits_for_the_trace_or_the_result():
    """Work deferred with while_compiling starts when a program has been traced
    (start_deferred), not before; asked for first, it runs then; once, either way; its
    error reaches the caller."""
    import threading

    from wfjax._parallel import start_deferred, while_compiling

    started = threading.Event()
    calls = []

    def work(x):
        calls.append(x)
        started.set()
        return x + 1

    deferred = while_compiling(work, 1)
    assert not started.wait(0.2) and calls == []  # nothing before the trace
    start_deferred()
    assert started.wait(10)
    assert deferred.result() == 2 and calls == [1]
    start_deferred()  # nothing left: no second run
    assert deferred.result() == 2 and calls == [1]

    asked_first = while_compiling(work, 5)
    assert asked_first.result() == 6 and calls == [1, 5]
    start_deferred()  # already run on demand: not again
    assert asked_first.result() == 6 and calls == [1, 5]

    def fail():
        raise ValueError("import failed")

    with pytest.raises(ValueError, match="import failed"):
        while_compiling(fail).result()
    start_deferred()

"""The restructured core reproduces the results of the code before issue 30's restructuring
(``tests/baselines.py`` wrote ``tests/data/issue30_baselines.npz`` at the commit it records,
from an empty cache).

Tolerance: ``REL`` = 1e-10 relative to the largest magnitude of each array, plus 1e-10 P absolute
on forces (the minima and histories near loss of contact sit near zero). It was 1e-12 until a
fresh install of 2026-12-05 (jax 0.10.2, numpy 2.4.6, scipy 1.17.1) moved the single runs by
2.2-3.4e-12 and the bogie by 1.4-2.3e-11 of their largest values with the code unchanged (the
commit before, 662156f, failed alike): the libraries' round-off, not the model. A change to the
model moves these results by 1e-6 or more."""

from __future__ import annotations

import baselines
import numpy as np
import pytest

P = 65e3 + 1e-9  # N, the default preload
# 3D tables or a 3D family from empty caches; the rough void sleeper (75 s: its modal model
# and roughness tables from an empty cache) and the detector (20 s) keep the default run
# under 10 minutes on CI's 2 cores
SLOW = {"default_sweep", "single/3d", "fit3d", "rough_void", "detector"}


REL = 1e-10  # relative tolerance: the libraries' round-off across installs (module docstring)


def _stored(case: str) -> dict:
    data = np.load(baselines.PATH)
    prefix = f"{case}::"
    return {k[len(prefix):]: data[k] for k in data.files if k.startswith(prefix)}


@pytest.mark.parametrize("case", [pytest.param(c, marks=pytest.mark.slow) if c in SLOW else c
                                  for c in baselines.CASES])
def test_results_equal_the_baseline(case, tmp_path, monkeypatch):
    # from an empty cache, as the baselines were written: 3D tables and families read from a
    # warm cache were built in another order (warm-started solves), which moves the default
    # sweep's maxima by ~1.6e-10 relative (measured: the baseline's own commit, 00125cf, fails
    # at 1e-12 on a warm cache and passes on an empty one)
    monkeypatch.setenv("WFJAX_CACHE_DIR", str(tmp_path))
    want = _stored(case)
    got = baselines.CASES[case]()
    assert set(got) == set(want)
    for key, ref in want.items():
        value = np.asarray(got[key])
        assert value.shape == ref.shape, key
        forces = any(w in key for w in ("force", "load", "peak"))
        bound = REL * np.max(np.abs(ref)) + (REL * P if forces else 0.0)
        assert np.max(np.abs(value - ref)) <= bound, (key, np.max(np.abs(value - ref)))

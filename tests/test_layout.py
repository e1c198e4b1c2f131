"""The house's promises that a reader can check: how far one follows a flat through simulate."""

import importlib.util
import pathlib

import wfjax as wf

_SCRIPT = pathlib.Path(__file__).parents[1] / "benchmarks" / "flat_stays.py"


def _flat_stays():
    spec = importlib.util.spec_from_file_location("flat_stays", _SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_following_a_flat_through_simulate_takes_at_most_15_stays():
    fs = _flat_stays()
    calls = fs.flat_calls(wf.Flat.rounded(depth=0.9e-3, length=0.1), speed=100 / 3.6,
                          contact="hertz-trajectory")
    stays = fs.stays(calls)
    modules = [m for m, _ in stays]
    assert modules[0] == "wfjax.api" and "wfjax.model.geometry" in modules
    assert len(stays) <= 15, stays

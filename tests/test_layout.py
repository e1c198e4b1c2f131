"""The house's promises that a reader can check: how far one follows a flat through simulate."""

import bench_scripts

import wfjax as wf


def test_following_a_flat_through_simulate_takes_at_most_15_stays():
    fs = bench_scripts.load("flat_stays")
    calls = fs.flat_calls(wf.Flat.rounded(depth=0.9e-3, length=0.1), speed=100 / 3.6,
                          contact="hertz-trajectory")
    stays = fs.stays(calls)
    modules = [m for m, _ in stays]
    assert modules[0] == "wfjax.api" and "wfjax.model.geometry" in modules
    assert len(stays) <= 15, stays

"""Physics guards (wfjax.scenario.guards, docs/convergence.md "Physics guards"): every numerical
setting swept across its bound is refused just outside it and accepted just inside, the
defaults pass with margin, a refusal is one line before any work, and the expert override
warns and lands in the provenance."""

import dataclasses
import itertools
import json
import time
import warnings

import numpy as np
import pytest

import wfjax as wf
from wfjax.cli import main
from wfjax.scenario import guards as G
from wfjax.scenario.description import Scenario

SPEEDS = np.array([5.0, 20.0, 40.0, 60.0, 83.3])  # m/s, up to 300 km/h
PAPER = {"wheel": wf.Wheel(), "material": wf.Material()}


def _scales(track=None):
    return G.scales(PAPER["wheel"], track or wf.Track(), PAPER["material"])


def _findings(contact="3d", speeds=SPEEDS, **changes):
    """Findings of a single wheel with ``changes`` ({"config": {...}, "track": {...}})."""
    config = wf.SimConfig(**changes.get("config", {}))
    track = wf.Track(**{"n_bays": 24, **changes.get("track", {})})  # holds the path
    sc = Scenario.of(wf.Flat.new(0.9e-3), contact, track=track, config=config,
                     sensors=changes.get("sensors"))
    return sc.guard_findings(speeds, changes.get("path", (-2.0, 3.0)))


def test_defaults_pass_with_margin():
    """Every default setting, the force's and a detector's reading's, is at most 0.8 of its
    bound, for both rail-head radii, at every speed up to 300 km/h and for every contact
    model."""
    margin = 0.8
    for cfg, track in itertools.product((wf.SimConfig().resolved(reading=r) for r in (False, True)),
                                        (wf.Track(), wf.Track.comparison())):
        sc = _scales(track)
        for v in SPEEDS:
            assert cfg.time_step_for(v) <= margin * G.STEP_FACTOR / sc.wheel_frequency
            assert v * cfg.time_step_for(v) <= margin * G.TRAVEL_FACTOR * sc.contact_length
        assert cfg.track_max_frequency * margin >= G.MODES_FACTOR * sc.wheel_frequency
        h = track.sleeper_spacing / track.elements_per_bay
        assert h <= margin * G.bending_wavelength(track, cfg.track_max_frequency) / G.MESH_FACTOR
        assert cfg.contact_element <= margin * G.ELEMENT_FACTOR * sc.contact_length
        for contact in ("3d", "2d", "hertz-trajectory", "hertz-profile"):
            assert _findings(contact) == []


def _bounds(track):
    """{(section, key): (the bound, the value's scaling)} of each numerical setting."""
    sc = _scales(track)
    dt = G.STEP_FACTOR / sc.wheel_frequency
    f_min = G.MODES_FACTOR * sc.wheel_frequency
    return {("config", "max_time_step"): dt, ("config", "track_max_frequency"): f_min,
            ("config", "contact_element"): G.ELEMENT_FACTOR * sc.contact_length}


@pytest.mark.parametrize("key", ["max_time_step", "track_max_frequency", "contact_element"])
def test_each_config_guard_refuses_outside_and_accepts_inside(key):
    bound = _bounds(wf.Track())[("config", key)]
    worse, better = (1.05, 0.95) if key != "track_max_frequency" else (0.95, 1.05)
    extra = {"max_travel_step": 1e-2} if key == "max_time_step" else {}
    speeds = [5.0] if key == "max_time_step" else SPEEDS  # where the time step binds
    out = _findings(config={key: bound * worse, **extra}, speeds=speeds)
    assert len(out) == 1 and out[0].startswith(f"config.{key} = "), out
    assert _findings(config={key: bound * better, **extra}, speeds=speeds) == []


def test_travel_step_guard_names_the_travel_step():
    """At 300 km/h the travel step sets the time step; its bound is TRAVEL_FACTOR 2a."""
    sc = _scales()
    v = 83.3
    bound = G.TRAVEL_FACTOR * sc.contact_length
    loose = {"max_time_step": 1e-3}
    assert _findings(speeds=[v], config={"max_travel_step": 1.05 * bound, **loose}
                     )[0].startswith("config.max_travel_step = ")
    assert _findings(speeds=[v], config={"max_travel_step": 0.95 * bound, **loose}) == []


def test_contact_element_is_not_checked_for_hertz():
    assert _findings("hertz-trajectory", config={"contact_element": 1e-2}) == []


def test_mesh_guard_follows_the_mode_cut_off():
    """Elements per bay below MESH_FACTOR per bending wavelength at the cut-off: refused;
    the bound moves with the cut-off (absorbing ends: the ends do not enter this guard, and
    each mesh's end network would be fitted when the scenario is made)."""
    track = wf.Track()
    for f in (10e3, 20e3):
        need = int(np.ceil(G.MESH_FACTOR * track.sleeper_spacing
                           / G.bending_wavelength(track, f)))
        out = _findings(config={"track_max_frequency": f},
                        track={"elements_per_bay": need - 1, "ends": "absorbing"})
        assert len(out) == 1 and out[0].startswith("track.elements_per_bay = "), out
        assert _findings(config={"track_max_frequency": f},
                         track={"elements_per_bay": need, "ends": "absorbing"}) == []


@pytest.mark.parametrize("ends", ["absorbing", "network"])
def test_track_end_guard_for_one_wheel_and_the_sensor_range(ends):
    track = wf.Track(n_bays=24, ends=ends)
    half = 0.5 * track.n_bays * track.sleeper_spacing
    m = G.end_margin(track)
    inside, outside = half - m - 0.05, half - m + 0.05
    assert _findings(path=(-1.0, inside), track={"ends": ends}) == []
    out = _findings(path=(-1.0, outside), track={"ends": ends})
    head = f"track.n_bays = {track.n_bays}: the wheels' path"
    assert len(out) == 1 and out[0].startswith(head), out
    assert ("end networks" in out[0]) == (ends == "network")
    s = half - G.sensor_margin(track)
    inside, outside = s - 0.05, s + 0.05
    assert _findings(sensors=[inside], track={"ends": ends}) == []
    if ends == "network":
        return
    # per-sleeper supports fix the track's length: a sensor too near its ends is refused
    fixed = wf.supports.with_supports(track, pad_stiffness=np.full(track.n_bays - 1,
                                                                   track.pad_stiffness))
    words = rf"allowed range .*\({G.sensor_margin(track):.2f} m clear of the ends"
    with pytest.raises(ValueError, match=f"sensor position {-outside:g} m is outside the {words}"):
        Scenario.of(wf.Flat.new(0.9e-3), "3d", track=fixed, sensors=[-outside])


def test_a_track_with_scalar_supports_is_lengthened_to_what_the_case_needs():
    """n_bays is the least length: sensors, detector bridges and every wheel's path get
    their guard margins from the clamped ends of the lengthened track, never fewer bays than
    asked; the lengthened track gives what the same track asked for explicitly gives."""
    track, flat = wf.Track(n_bays=8), wf.Flat.new(0.9e-3)
    half = lambda t: 0.5 * t.n_bays * t.sleeper_spacing  # noqa: E731
    sc = Scenario.of(flat, "hertz-trajectory", track=track, sensors=[5.0])
    assert half(sc.track) - 5.0 >= G.sensor_margin(track) > half(sc.track) - 5.0 - 0.65
    assert sc.track.n_bays % 2 == 0
    sc = Scenario.of(flat, "hertz-trajectory", track=track, detector=wf.Detector(5, 3))
    assert half(sc.track) - 6.0 * 0.6 >= G.sensor_margin(track)
    bogie = Scenario.of(flat, "hertz-trajectory", track=track, vehicle=wf.Vehicle.bogie())
    v, pos = bogie.speeds([300 / 3.6]), bogie.positions(10)
    long = bogie.lengthened([bogie.window_flat(flat)], v, pos)
    lo, hi = long.path(long.window_flat(flat), v, pos)
    offsets = long.vehicle.offsets()
    edge = max(hi + offsets.max(), -(lo + offsets.min()))
    assert half(long.track) - edge >= G.end_margin(track) > half(long.track) - edge - 0.65
    default = wf.Scenario.of(flat, "3d").lengthened([flat], v, pos)  # end networks
    lo, hi = default.path(default.window_flat(flat), v, pos)
    assert half(default.track) - max(hi, -lo) >= G.end_margin(default.track)
    assert wf.Track().n_bays < default.track.n_bays < wf.params.ABSORBING_BAYS
    short = wf.simulate(flat, 100 / 3.6, contact="hertz-trajectory", track=wf.Track(),
                        impact_position=0.2)
    n = Scenario.of(flat, "hertz-trajectory", track=wf.Track()).lengthened(
        [flat], [100 / 3.6], [0.2]).track.n_bays
    assert n > wf.Track().n_bays
    same = wf.simulate(flat, 100 / 3.6, contact="hertz-trajectory",
                       track=wf.Track(n_bays=n), impact_position=0.2)
    np.testing.assert_array_equal(short.force, same.force)


def test_refusal_is_one_line_before_any_work(tmp_path, capsys):
    out = tmp_path / "o"
    t0 = time.monotonic()
    code = main(["simulate", "--contact", "hertz-trajectory", "--set",
                 "config.track_max_frequency=100", "--out", str(out)])
    assert code == 2 and time.monotonic() - t0 < 20
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "config.track_max_frequency = 100 Hz" in err[0], err
    assert "--allow-inaccurate" in err[0]
    assert not out.exists()


def test_override_warns_and_is_recorded_in_the_provenance():
    from wfjax import case as C
    from wfjax.commands._common import provenance

    config = wf.SimConfig(track_max_frequency=100.0, allow_inaccurate=True)
    sc = Scenario.of(wf.Flat.new(0.9e-3), "hertz-trajectory", config=config,
                     track=wf.Track(n_bays=24))
    with G.recorded() as notes, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sc.check_settings(sc.window_flat(sc.flats[0]), [30.0], [0.1])
        prov = provenance(C.resolve("simulate", None, {}))
    assert len(notes) == 1 and "track_max_frequency" in notes[0]
    assert any(issubclass(w.category, G.AccuracyWarning) for w in caught)
    assert json.loads(json.dumps(prov))["accuracy_warnings"] == notes
    assert G.notes() == []  # nothing leaks out of the block


def test_refusal_without_the_override_names_setting_value_bound_and_reason():
    config = wf.SimConfig(max_time_step=1e-3, max_travel_step=1e-1)
    sc = Scenario.of(wf.Flat.new(0.9e-3), "hertz-trajectory", config=config)
    with pytest.raises(G.InaccurateSettings) as e:
        sc.check_settings(sc.window_flat(sc.flats[0]), [30.0], [0.1])
    text = str(e.value)
    assert "\n" not in text
    for word in ("config.max_time_step = 1000 us", "above", "f_W", "3 %"):
        assert word in text, text
    # the Python API gets the same refusal from simulate, before any work
    with pytest.raises(G.InaccurateSettings):
        wf.simulate(wf.Flat.new(0.9e-3), 30.0, contact="hertz-trajectory",
                    config=dataclasses.replace(config))


def test_fit_models_are_guarded_before_compiling(monkeypatch):
    from wfjax.fit import models

    def never(*args, **kwargs):
        raise AssertionError("compiled before the guards ran")

    monkeypatch.setattr(models, "compile_scenario", never)
    with pytest.raises(G.InaccurateSettings, match="config.track_max_frequency = 100 Hz"):
        models.max_force_model([30.0], wf.Flat.rounded(0.9e-3, 0.1),
                               config=wf.SimConfig(track_max_frequency=100.0))

"""Labelled results (wfjax.labelled): SweepResult.to_xarray / to_dataframe / to_netcdf and
``wfjax sweep --format``.

One real sweep covers every array a SweepResult can carry: a bogie (wheel), two rail
roughness realisations (realisation), sensors (quantity x sensor position) and a detector
(bay); hertz-trajectory contact, two depths of one flat kind (one compile), two speeds, one
impact position, a coarse time step.
"""

import csv
import io
import json
import sys

import numpy as np
import pytest

import wfjax as wf
from wfjax import case as C
from wfjax import labelled as L
from wfjax.cli import main
from wfjax.model.vehicle import Vehicle
from wfjax.scenario import roughness as R
from wfjax.scenario.sensors import Detector

xr = pytest.importorskip("xarray")  # in the test extra: wfjax[test] installs it
TINY = ["--contact", "hertz-trajectory", "--speeds-kmh", "60,120", "--positions", "1"]
COARSE = wf.SimConfig(max_travel_step=2e-3, max_time_step=5e-5)
LABELS = ("speeds", "impact_positions", "flats", "contact", "depths", "lengths",
          "sensor_positions", "sensor_quantities", "detector_bays", "wheel_positions",
          "flat_wheel", "settings")  # the SweepResult fields that label the arrays' axes or
# describe the runs (settings: the Dataset's attrs)


@pytest.fixture(scope="module", name="full")
def _full():
    """A sweep with every optional output: [2 flats, 2 speeds, 1 position] x 2 wheels,
    2 realisations, 2 quantities x 2 sensors, 2 bays."""
    rough = R.generate(R.ISO3095_LIMIT, key=0, length=10.0, x_start=-5.0, n_realisations=2)
    flats = [wf.Flat.rounded(0.9e-3, 0.1), wf.Flat.rounded(0.6e-3, 0.1)]
    return wf.sweep(flats, [60 / 3.6, 120 / 3.6], [0.1], contact="hertz-trajectory",
                    vehicle=Vehicle.bogie(), sensors=[0.0, 0.325],
                    sensor_quantities=("shear", "seat_force"),
                    detector=Detector(n_bays=2, first_bay=0), roughness=rough, config=COARSE,
                    progress=False)


def _one_wheel(res):
    """``res`` as a sweep without a vehicle reports it (the detector without a wheel axis)."""
    return res._replace(wheel_max_force=None, wheel_min_force=None, wheel_loss_of_contact=None,
                        wheel_axle_acc_peak=None, wheel_positions=None,
                        detector_peak=res.detector_peak[..., 0, :],
                        detector_ratio=res.detector_ratio[..., 0, :])


def test_every_array_has_named_dimensions_in_the_csv_units(full):
    ds = full.to_xarray()
    run = ("flat", "speed_kmh", "impact_position_mm")
    want = {"max_force_kN": run, "min_force_kN": run, "loss_of_contact": run,
            "loss_of_contact_ms": run, "max_residual_m": run, "axle_acc_peak_m_s2": run,
            "wheel_max_force_kN": run + ("wheel",), "wheel_min_force_kN": run + ("wheel",),
            "wheel_loss_of_contact": run + ("wheel",),
            "wheel_axle_acc_peak_m_s2": run + ("wheel",),
            "realisation_max_force_kN": run + ("realisation",),
            "realisation_min_force_kN": run + ("realisation",),
            "sensor_max": run + ("quantity", "sensor_m"),
            "sensor_min": run + ("quantity", "sensor_m"),
            "detector_peak_kN": run + ("wheel", "bay"), "detector_ratio": run + ("wheel", "bay")}
    assert {k: v.dims for k, v in ds.data_vars.items()} == want
    assert dict(ds.sizes) == {"flat": 2, "speed_kmh": 2, "impact_position_mm": 1, "wheel": 2,
                              "realisation": 2, "quantity": 2, "sensor_m": 2, "bay": 2}
    # every array field of the result is a variable; every labelling field a coordinate
    arrays = [f for f in full._fields if f not in LABELS and getattr(full, f) is not None]
    assert len(arrays) == len(want)
    assert json.loads(ds.attrs["settings"]) == full.settings
    # values in the CSV's units, coordinates too
    np.testing.assert_allclose(ds["max_force_kN"], np.asarray(full.max_force) / 1e3, rtol=1e-15)
    np.testing.assert_allclose(ds["loss_of_contact_ms"],
                               np.asarray(full.loss_of_contact_duration) * 1e3, rtol=1e-15)
    np.testing.assert_allclose(ds["wheel_max_force_kN"][..., 1],
                               np.asarray(full.wheel_max_force)[..., 1] / 1e3, rtol=1e-15)
    np.testing.assert_allclose(ds["realisation_max_force_kN"].max("realisation"),
                               ds["max_force_kN"], rtol=1e-15)
    np.testing.assert_allclose(ds["sensor_max"].sel(quantity="seat_force", sensor_m=0.325),
                               np.asarray(full.sensor_max)[..., 1, 1], rtol=1e-15)
    np.testing.assert_allclose(ds["detector_peak_kN"].sel(bay=1, wheel=1),
                               np.asarray(full.detector_peak)[..., 1, 1] / 1e3, rtol=1e-15)
    assert ds["max_force_kN"].attrs["units"] == "kN"
    assert ds["loss_of_contact"].dtype == bool
    assert list(ds["speed_kmh"].values) == pytest.approx([60.0, 120.0], rel=1e-12)
    assert ds["speed_kmh"].attrs["units"] == "km/h"
    assert list(ds["impact_position_mm"].values) == pytest.approx([100.0])
    assert list(ds["depth_mm"].values) == pytest.approx([0.9, 0.6])
    assert list(ds["flat"].values) == list(full.flats)
    assert list(ds["wheel_position_m"].values) == pytest.approx([0.0, 2.5])
    assert list(ds["quantity"].values) == ["shear", "seat_force"]
    assert list(ds["quantity_units"].values) == ["N", "N"]
    assert list(ds["sensor_m"].values) == [0.0, 0.325] and list(ds["bay"].values) == [0, 1]
    assert ds.attrs["contact"] == "hertz-trajectory" and ds.attrs["flat_wheel"] == 0
    assert json.loads(ds.attrs["provenance"])["wfjax_version"] == wf.__version__


def test_without_a_vehicle_the_detector_has_no_wheel_axis(full):
    ds = _one_wheel(full).to_xarray()
    assert "wheel" not in ds.dims and "flat_wheel" not in ds.attrs
    assert ds["detector_peak_kN"].dims == ("flat", "speed_kmh", "impact_position_mm", "bay")
    assert list(L.TABLES) == ["runs", "wheels", "realisations", "sensors", "detector"]
    with pytest.raises(ValueError, match="'wheels' is not in this sweep; it has: runs, "
                                         "realisations, sensors, detector"):
        _one_wheel(full).to_dataframe("wheels")


def test_netcdf_round_trip_gives_the_same_numbers_and_case(full, tmp_path):
    case = C.resolve("sweep", None, {"run.contact": "hertz-trajectory"}, environ={})
    path = full.to_netcdf(tmp_path / "r.nc", case=case, provenance={"command": "test"})
    assert path.read_bytes()[:4] == b"CDF\x02"  # NetCDF 3 (64-bit offsets): SciPy's writer
    assert [p.name for p in tmp_path.iterdir()] == ["r.nc"]  # no temporary left
    back = L.open_netcdf(path)
    xr.testing.assert_identical(back, full.to_xarray(case, {"command": "test"}))
    assert L.case_of(back) == case.to_dict()
    assert C.resolve("sweep", None, {}, environ={}).to_dict() != case.to_dict()  # it tells
    assert L.provenance_of(back) == {"command": "test"}
    np.testing.assert_allclose(back["max_force_kN"].values * 1e3, full.max_force, rtol=1e-15)
    np.testing.assert_allclose(back["detector_peak_kN"].values * 1e3, full.detector_peak,
                               rtol=1e-15)
    np.testing.assert_array_equal(back["wheel_loss_of_contact"].values,
                                  np.asarray(full.wheel_loss_of_contact))
    assert back["flat"].values.tolist() == list(full.flats)


def test_runs_frame_is_the_csv_and_every_table_has_its_index(full):
    frame = full.to_dataframe()
    rows = list(csv.DictReader(io.StringIO(full.to_csv())))
    assert len(frame) == len(rows) == 4
    flat = frame.reset_index()
    for col in ("speed_kmh", "impact_position_mm", "max_force_kN", "min_force_kN",
                "loss_of_contact_ms", "depth_mm", "length_mm"):
        assert flat[col].to_numpy() == pytest.approx([float(r[col]) for r in rows], abs=1e-6)
    assert flat["flat"].tolist() == [r["flat"] for r in rows]
    assert flat["loss_of_contact"].astype(int).tolist() == [int(r["loss_of_contact"])
                                                            for r in rows]
    idx = {t: list(full.to_dataframe(t).index.names) for t in L.TABLES}
    run = ["flat", "speed_kmh", "impact_position_mm"]
    assert idx == {"runs": run, "wheels": run + ["wheel"], "realisations": run + ["realisation"],
                   "sensors": run + ["quantity", "sensor_m"],
                   "detector": run + ["wheel", "bay"]}
    sensors = full.to_dataframe("sensors")
    assert len(sensors) == 4 * 2 * 2 and set(sensors.columns) >= {"sensor_max", "sensor_min"}
    with pytest.raises(ValueError, match="'nonsense' is not in this sweep"):
        full.to_dataframe("nonsense")


@pytest.mark.parametrize("missing", ["xarray", "pandas"])
def test_missing_optional_dependency_is_one_line_naming_the_extra(full, tmp_path, monkeypatch,
                                                                  missing):
    monkeypatch.setitem(sys.modules, missing, None)
    for call in (full.to_xarray, full.to_dataframe, lambda: full.to_netcdf(tmp_path / "x.nc")):
        with pytest.raises(ImportError) as err:
            call()
        text = str(err.value)
        assert "\n" not in text and missing in text and "pip install 'wfjax[io]'" in text
    assert not list(tmp_path.iterdir())


def test_sweep_format_netcdf_writes_the_labelled_file(tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["sweep", *TINY, "--flat", "new", "--format", "csv,netcdf",
                 "--out", str(out)]) == 0
    assert "sweep.csv, sweep.nc" in capsys.readouterr().out
    ds = L.open_netcdf(out / "sweep.nc")
    summary = json.loads((out / "sweep.json").read_text())
    assert L.case_of(ds) == summary["case"] and L.provenance_of(ds) == summary["provenance"]
    npz = wf.SweepResult.load_npz(out / "sweep.npz")
    np.testing.assert_allclose(ds["max_force_kN"].values * 1e3, npz.max_force, rtol=1e-15)
    rows = list(csv.DictReader((out / "sweep.csv").open()))
    assert ds["min_force_kN"].values.ravel() == pytest.approx(
        [float(r["min_force_kN"]) for r in rows], abs=1e-6)
    only = tmp_path / "n"  # the same case from its JSON summary, NetCDF alone
    assert main(["sweep", "--config", str(out / "sweep.json"), "--format", "netcdf",
                 "--out", str(only)]) == 0
    assert not (only / "sweep.csv").exists()
    xr.testing.assert_identical(L.open_netcdf(only / "sweep.nc"), ds)



@pytest.mark.parametrize("argv, missing, words", [
    (["--format", "netcdf"], "xarray", "--format netcdf needs xarray, not installed: "
                                       "pip install 'wfjax[io]'"),
    (["--format", "csv,netcdf"], "pandas", "needs pandas, not installed: pip install "
                                           "'wfjax[io]'"),
    (["--format", "hdf5"], None, 'error: --format "hdf5": not one of the choices; allowed: '
                                 "csv | netcdf (or a list of them)"),
    (["--format", "csv,parquet"], None, "allowed: csv | netcdf"),
])
def test_bad_format_or_missing_dependency_exit_2_one_line_nothing_written(
        tmp_path, capsys, monkeypatch, no_work, argv, missing, words):
    if missing:
        monkeypatch.setitem(sys.modules, missing, None)
    monkeypatch.chdir(tmp_path)
    assert main(["sweep", *TINY, *argv, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("wfjax sweep: error: "), err
    assert words in err[0], err[0]
    assert not list(tmp_path.iterdir())

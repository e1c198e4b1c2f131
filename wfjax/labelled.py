"""Labelled results: a :class:`wfjax.sweeps.SweepResult` as an xarray ``Dataset``, a pandas
``DataFrame`` or a NetCDF file, with named dimensions and the units of ``sweep.csv``.

Dimensions (:data:`DIMS`, then those of :data:`TABLES`), each with a coordinate:

* ``flat`` (the flats' labels, with ``depth_mm`` and ``length_mm`` along it),
  ``speed_kmh`` [km/h], ``impact_position_mm`` [mm]: every run;
* ``wheel`` (with ``wheel_position_m``, the distance behind the leading wheel [m]): a
  vehicle's every wheel;
* ``realisation``: the roughness or support realisations of a Monte Carlo sweep;
* ``quantity`` (with ``quantity_units``) x ``sensor_m`` [m]: the fixed rail sensors;
* ``bay``: the detector's bay indices.

Variables carry the names of the CSV columns (``max_force_kN``, ``loss_of_contact_ms``, ...)
and a ``units`` attribute; the sensors' extremes are in SI units (``quantity_units``). The
dataset's attributes hold the resolved case and the provenance as JSON strings (NetCDF
attributes cannot nest): :func:`case_of`, :func:`provenance_of` read them back.

xarray and pandas are optional (``pip install 'wfjax[io]'``); NetCDF files are written with
xarray's ``scipy`` engine (NetCDF 3, 64-bit offsets): SciPy is a dependency of wfjax already,
so no HDF5 library is needed, and every NetCDF reader opens the files.
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path
from typing import Any

import numpy as np

from .scenario.sensors import UNITS as SENSOR_UNITS

__all__ = ["DIMS", "TABLES", "INSTALL", "require", "to_xarray", "to_dataframe", "to_netcdf",
           "open_netcdf", "case_of", "provenance_of"]

INSTALL = "pip install 'wfjax[io]'"
DIMS = ("flat", "speed_kmh", "impact_position_mm")
"""The dimensions of every run's summary values, in the order of ``SweepResult``'s axes."""
TABLES = {"runs": (), "wheels": ("wheel",), "realisations": ("realisation",),
          "sensors": ("quantity", "sensor_m"), "detector": ("bay",)}
""":func:`to_dataframe`'s tables: the dimensions each adds to :data:`DIMS` (the detector's
readings have ``wheel`` too when the sweep had a vehicle)."""

# SweepResult field -> (variable, factor from SI, units, meaning, trailing dimensions)
_VARIABLES = (
    ("max_force", "max_force_kN", 1e-3, "kN", "maximum contact force after the run-in", ()),
    ("min_force", "min_force_kN", 1e-3, "kN", "minimum contact force after the run-in", ()),
    ("loss_of_contact", "loss_of_contact", None, None, "F = 0 occurred", ()),
    ("loss_of_contact_duration", "loss_of_contact_ms", 1e3, "ms", "time with F = 0", ()),
    ("max_residual", "max_residual_m", 1.0, "m", "largest contact-equation residual", ()),
    ("axle_acc_peak", "axle_acc_peak_m_s2", 1.0, "m/s^2",
     "max |axle-box acceleration| of the flat's wheel after the run-in", ()),
    ("wheel_max_force", "wheel_max_force_kN", 1e-3, "kN", "every wheel's maximum contact force",
     ("wheel",)),
    ("wheel_min_force", "wheel_min_force_kN", 1e-3, "kN", "every wheel's minimum contact force",
     ("wheel",)),
    ("wheel_loss_of_contact", "wheel_loss_of_contact", None, None, "F = 0 occurred at the wheel",
     ("wheel",)),
    ("wheel_axle_acc_peak", "wheel_axle_acc_peak_m_s2", 1.0, "m/s^2",
     "every wheel's max |axle-box acceleration|", ("wheel",)),
    ("realisation_max_force", "realisation_max_force_kN", 1e-3, "kN",
     "maximum contact force on each realisation", ("realisation",)),
    ("realisation_min_force", "realisation_min_force_kN", 1e-3, "kN",
     "minimum contact force on each realisation", ("realisation",)),
    ("sensor_max", "sensor_max", 1.0, None, "sensor maximum after the run-in (SI units: "
     "quantity_units)", ("quantity", "sensor_m")),
    ("sensor_min", "sensor_min", 1.0, None, "sensor minimum after the run-in (SI units: "
     "quantity_units)", ("quantity", "sensor_m")),
    ("detector_peak", "detector_peak_kN", 1e-3, "kN", "detector reading per bay",
     ("wheel", "bay")),
    ("detector_ratio", "detector_ratio", 1.0, "1", "detector reading / static wheel load",
     ("wheel", "bay")),
)


def require(what: str = "labelled results"):
    """xarray (imported), or ImportError whose one-line message names what to install.

    Args:
        what: what needs them, the start of the message (e.g. ``"--format netcdf"``).
    """
    missing = []
    for name in ("xarray", "pandas"):
        try:
            importlib.import_module(name)
        except ImportError:
            missing.append(name)
    if missing:
        raise ImportError(f"{what} needs {' and '.join(missing)}, not installed: {INSTALL}")
    return importlib.import_module("xarray")


def _coords(result) -> dict:
    """The coordinates of every dimension ``result`` has, in the units of the CSV."""
    coords: dict[str, Any] = {
        "flat": ("flat", np.array(result.flats, dtype=str), {"long_name": "flat"}),
        "speed_kmh": ("speed_kmh", np.asarray(result.speeds, dtype=float) * 3.6,
                      {"units": "km/h", "long_name": "train speed"}),
        "impact_position_mm": ("impact_position_mm",
                               np.asarray(result.impact_positions, dtype=float) * 1e3,
                               {"units": "mm", "long_name": "impact position within the bay"}),
    }
    for name, values, text in (("depth_mm", result.depths, "flat depth"),
                               ("length_mm", result.lengths, "flat length")):
        if values is not None:
            coords[name] = ("flat", np.asarray(values, dtype=float) * 1e3,
                            {"units": "mm", "long_name": text})
    if result.wheel_positions is not None:
        n = np.size(result.wheel_positions)
        coords["wheel"] = ("wheel", np.arange(n), {"long_name": "wheel (0 = leading)"})
        coords["wheel_position_m"] = ("wheel", np.asarray(result.wheel_positions, dtype=float),
                                      {"units": "m", "long_name": "distance behind the leading "
                                       "wheel"})
    if result.realisation_max_force is not None:
        n = np.shape(result.realisation_max_force)[-1]
        coords["realisation"] = ("realisation", np.arange(n),
                                 {"long_name": "roughness or support realisation"})
    if result.sensor_positions is not None:
        names = tuple(result.sensor_quantities)
        coords["quantity"] = ("quantity", np.array(names, dtype=str),
                              {"long_name": "sensor quantity"})
        coords["quantity_units"] = ("quantity", np.array([SENSOR_UNITS[q] for q in names]),
                                    {"long_name": "SI unit of the quantity"})
        coords["sensor_m"] = ("sensor_m", np.asarray(result.sensor_positions, dtype=float),
                              {"units": "m", "long_name": "sensor position on the rail"})
    if result.detector_bays is not None:
        coords["bay"] = ("bay", np.asarray(result.detector_bays).astype(np.int32),
                         {"long_name": "detector bay index (0 spans [0, L_S))"})
    return coords


def _variables(result) -> dict:
    """Every array ``result`` holds, as ``name: (dims, values, attrs)`` in the CSV's units."""
    out = {}
    for field, name, factor, units, meaning, trailing in _VARIABLES:
        values = getattr(result, field)
        if values is None:
            continue
        values = np.asarray(values)
        extra = values.ndim - len(DIMS)
        dims = DIMS + (trailing[len(trailing) - extra:] if extra else ())
        values = values.astype(bool) if factor is None else values.astype(float) * factor
        attrs = {"long_name": meaning} | ({"units": units} if units else {})
        out[name] = (dims, values, attrs)
    return out


def _base_provenance() -> dict:
    """wfjax's and JAX's versions and the devices: the provenance of a library call."""
    import jax

    import wfjax

    return {"wfjax_version": wfjax.__version__, "jax_version": jax.__version__,
            "jax_backend": jax.default_backend(), "jax_device_count": jax.device_count()}


def to_xarray(result, case=None, provenance: dict | None = None):
    """``result`` as an ``xarray.Dataset`` with named dimensions and units (module doc).

    Args:
        result: a :class:`wfjax.sweeps.SweepResult`.
        case: the resolved case (a :class:`wfjax.case.Case` or its ``to_dict()``), stored as
            the JSON attribute ``case``; None: no such attribute.
        provenance: what made the result (``wfjax sweep`` passes its JSON summary's); None:
            wfjax's and JAX's versions and the devices. Stored as the JSON attribute
            ``provenance``; ``result.settings`` (the numerical settings as resolved) as the
            JSON attribute ``settings``.

    Returns:
        Dataset with dimensions ``flat`` x ``speed_kmh`` x ``impact_position_mm`` (and
        ``wheel``, ``realisation``, ``quantity`` x ``sensor_m``, ``bay`` where the sweep has
        them); forces in kN, durations in ms, speeds in km/h, positions in mm or m.

    Raises:
        ImportError: xarray or pandas not installed (one line naming ``wfjax[io]``).
    """
    xr = require("SweepResult.to_xarray")
    if case is not None and hasattr(case, "to_dict"):
        case = case.to_dict()
    attrs = {"title": "wfjax sweep", "contact": str(result.contact)}
    if result.wheel_positions is not None:
        attrs["flat_wheel"] = int(result.flat_wheel)
    if result.settings is not None:  # the numerical settings as resolved (JSON, as the case)
        attrs["settings"] = json.dumps(result.settings)
    if case is not None:
        attrs["case"] = json.dumps(case)
    attrs["provenance"] = json.dumps(_base_provenance() if provenance is None else provenance)
    return xr.Dataset(_variables(result), coords=_coords(result), attrs=attrs)


def to_dataframe(result, table: str = "runs", case=None, provenance: dict | None = None):
    """One of ``result``'s :data:`TABLES` as a long ``pandas.DataFrame``.

    Args:
        result: a :class:`wfjax.sweeps.SweepResult`.
        table: ``"runs"`` (one row per flat x speed x position, the columns of ``sweep.csv``),
            ``"wheels"``, ``"realisations"``, ``"sensors"`` or ``"detector"``.
        case, provenance: as :func:`to_xarray`, kept in the frame's ``attrs``.

    Returns:
        DataFrame indexed by the table's dimensions (``flat``, ``speed_kmh``,
        ``impact_position_mm``, ...), one column per variable and per coordinate along them.

    Raises:
        ValueError: ``table`` unknown, or not in this sweep (the message names those it has).
        ImportError: xarray or pandas not installed.
    """
    ds = to_xarray(result, case, provenance)
    have = {t: _table_variables(ds, dims) for t, dims in TABLES.items()}
    have = {t: names for t, names in have.items() if names}
    if table not in have:
        raise ValueError(f"table {table!r} is not in this sweep; it has: {', '.join(have)}")
    names = have[table]
    frame = ds[names].to_dataframe(dim_order=list(ds[names[0]].dims))
    frame.attrs = dict(ds.attrs)
    return frame


def _table_variables(ds, trailing: tuple) -> list[str]:
    """The variables of ``ds`` whose dimensions are :data:`DIMS` + ``trailing`` (the
    detector's: any with ``bay``)."""
    if trailing == ("bay",):
        return [k for k, v in ds.data_vars.items() if "bay" in v.dims]
    return [k for k, v in ds.data_vars.items() if v.dims == DIMS + trailing]


def to_netcdf(result, path, case=None, provenance: dict | None = None,
              engine: str = "scipy") -> Path:
    """Write :func:`to_xarray`'s dataset to ``path`` (NetCDF), atomically.

    Args:
        result, case, provenance: as :func:`to_xarray`.
        path: the file (conventionally ``.nc``).
        engine: xarray's writer; ``"scipy"`` (NetCDF 3) needs no further package,
            ``"netcdf4"``/``"h5netcdf"`` write NetCDF 4 where those are installed.

    Returns:
        ``path``. Nothing is left at ``path`` or beside it when writing fails.
    """
    ds = to_xarray(result, case, provenance)
    from .outputs import stage

    path = Path(path)
    stage(path, lambda target: ds.to_netcdf(target, engine=engine))
    return path


def open_netcdf(path):
    """A NetCDF file written by :func:`to_netcdf`, read into memory (the file is closed)."""
    xr = require("open_netcdf")
    with xr.open_dataset(path) as ds:
        return ds.load()


def case_of(ds) -> dict | None:
    """The resolved case stored in a labelled dataset (``{section: {key: value}}``), or None."""
    text = ds.attrs.get("case")
    return None if text is None else json.loads(text)


def provenance_of(ds) -> dict:
    """The provenance stored in a labelled dataset (wfjax and JAX versions, devices, ...)."""
    return json.loads(ds.attrs["provenance"])

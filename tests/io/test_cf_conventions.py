"""Files follow the CF conventions (oracle: the IOOS compliance-checker, CF-1.11) and read back unchanged.

Checked: an in-memory recording with a segment table written by :func:`calib.io.recording.write`, a long
recording streamed by :class:`calib.io.recording.LongRecordingWriter`, the navigation output of a real
navigation run, and a product written by :func:`calib.io.netcdf.write_netcdf` without explicit provenance.
The only findings allowed are the documented deviations of ``tools/cf_check.py`` (time is seconds from the
first sample, not a CF "since <epoch>" time; label coordinates are strings).
"""
from __future__ import annotations

import importlib.util
from pathlib import Path

import netCDF4
import numpy as np
import pytest
import xarray as xr

from calib.io import netcdf, recording
from calib.nav import navigation

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("cf_check", ROOT / "tools" / "cf_check.py")
cf_check = importlib.util.module_from_spec(spec)
spec.loader.exec_module(cf_check)


def _segments(n_seg=2):
    return {"segment_kind": ["static", "rotation"][:n_seg], "segment_label": ["z up", "turn about z"][:n_seg],
            "rotation_axis": np.array([[0, 0, 1.0], [0, 0, 1.0]])[:n_seg],
            "rotation_rate": np.array([0.0, 10.0])[:n_seg], "nominal_attitude": np.stack([np.eye(3)] * n_seg)}


def _recording(path, gyro_units="deg s-1"):
    n, fs = 400, 100.0
    rng = np.random.default_rng(1)
    acc = np.tile([0.0, 0.0, 9.8], (n, 1)) + 1e-3 * rng.standard_normal((n, 3))
    gyr = 1e-3 * rng.standard_normal((n, 3))
    seg = np.r_[np.zeros(200, int), np.ones(200, int)]
    ds = recording.make_dataset(acc, gyr, sample_rate_hz=fs, latitude_deg=30.5, accel_units="m s-2",
                                gyro_units=gyro_units, temperature=np.full(n, 25.0), segment_index=seg,
                                segments=_segments(), table_angle=np.r_[np.zeros(200), np.arange(200) * 0.1])
    return recording.write(ds, path)


def test_recording_is_cf_and_reads_back_in_calib_units(tmp_path):
    p = _recording(tmp_path / "rec.nc")
    assert cf_check.problems(p) == []
    with netCDF4.Dataset(p) as nc:
        assert nc.getncattr("Conventions") == "CF-1.11 calib-recording-1"
        assert "conventions" not in nc.ncattrs()
        assert nc.variables["gyro"].getncattr("units") == "degree s-1"          # UDUNITS spelling on disk
        assert nc.variables["table_angle"].getncattr("units") == "degree"
        assert nc.variables["time"].getncattr("units") == "s"
        assert "_FillValue" not in nc.variables["time"].ncattrs()
        for att in ("calib_version", "git_commit", "made_by_rule"):             # provenance without asking
            assert att in nc.ncattrs()
    h = recording.read_header(p)
    assert h.gyro_units == "deg s-1" and h.accel_units == "m s-2"
    ds = recording.load(p)
    assert ds["gyro"].attrs["units"] == "deg s-1" and ds["rotation_rate"].attrs["units"] == "deg s-1"


def test_recording_of_an_earlier_version_still_reads(tmp_path):
    """Files written before the CF attribute (lower-case ``conventions``, ``deg s-1``) are still recordings."""
    p = _recording(tmp_path / "old.nc")
    with netCDF4.Dataset(p, "a") as nc:
        nc.delncattr("Conventions")
        nc.setncattr("conventions", "calib-recording-1")
        nc.variables["gyro"].setncattr("units", "deg s-1")
    assert recording.validate(p).gyro_units == "deg s-1"


def test_not_a_recording_is_refused_by_its_conventions(tmp_path):
    p = tmp_path / "x.nc"
    xr.Dataset({"a": ("time", np.arange(3.0))}).to_netcdf(p)
    with pytest.raises(recording.RecordingError, match="Conventions"):
        recording.read_header(p)


def test_long_recording_and_navigation_output_are_cf(tmp_path):
    n, fs = 6000, 100.0
    w_e = 7.292115e-5
    lat = np.radians(30.5)
    acc = np.tile([0.0, 0.0, 9.79 / fs], (n, 1))                         # m/s per sample, level, at rest
    gyr = np.tile([0.0, w_e * np.cos(lat) / fs, w_e * np.sin(lat) / fs], (n, 1))
    p = tmp_path / "long.nc"
    with recording.LongRecordingWriter(p, n, fs, latitude_deg=30.5, accel_units="m s-1", gyro_units="rad",
                                       extra_attrs={"attitude_pitch_deg": 0.0, "attitude_roll_deg": 0.0,
                                                    "attitude_yaw_deg": 0.0}) as w:
        w.append(acc, gyr)
    assert cf_check.problems(p) == []
    with netCDF4.Dataset(p) as nc:
        assert nc.getncattr("Conventions") == "CF-1.11 calib-recording-1"
    nav = navigation.navigate_recording(p, output_interval_s=1.0)
    assert nav["time"].attrs["units"] == "s" and nav["time"].values[-1] == pytest.approx(60.0)
    out = netcdf.write_netcdf(nav, tmp_path / "nav.nc")
    assert cf_check.problems(out) == []
    with netCDF4.Dataset(out) as nc:
        assert nc.getncattr("Conventions") == "CF-1.11"
        assert "calib_version" in nc.ncattrs()


def test_checker_finds_a_defect(tmp_path):
    """The oracle can fail: a unit UDUNITS does not know and a variable without a name are found."""
    p = tmp_path / "bad.nc"
    xr.Dataset({"a": ("t", np.arange(3.0), {"units": "furlongs per fortnight!"})},
               attrs={"Conventions": "CF-1.11"}).to_netcdf(p)
    found = " ".join(cf_check.problems(p))
    assert "not recognized by UDUNITS" in found and "long_name" in found

"""Partial records: a recording of accelerometers only or gyroscopes only is declared (the absent triad left out of
the import settings; ``absent_sensors`` in the netCDF file), never zero-filled. Each command does what the triad it
holds allows, and one that needs the other triad names it; a constant placeholder channel is named as such, not as
a unit mistake."""
from __future__ import annotations

import json

import netCDF4
import numpy as np
import pytest

from calib import cli
from calib.ingest import importers
from calib.ingest.common import ImportDataError
from calib.io import recording
from calib.io.recording import RecordingError

FS = 100.0
G = 9.80665


def static(n=3000, seed=0):
    rng = np.random.default_rng(seed)
    acc = np.array([0.1, -0.2, G]) + 0.02 * rng.standard_normal((n, 3))
    gyr = np.array([2e-3, -1e-3, 4e-3]) + 2e-3 * rng.standard_normal((n, 3))   # a MEMS gyro's bias and noise
    return acc, gyr


def columns_settings(tmp_path, **triads):
    s = {"format": "columns", "file": "log.csv", "data_dir": str(tmp_path), "delimiter": ",", "header": True,
         "sample_rate_hz": FS, "latitude_deg": 48.0}
    s.update(triads)
    return s


def write_csv(path, acc, gyr):
    cols = ["ax", "ay", "az", "gx", "gy", "gz"]
    np.savetxt(path, np.column_stack([acc, gyr]), delimiter=",", header=",".join(cols), comments="")


def test_columns_and_npz_import_one_triad_declared_absent(tmp_path):
    acc, gyr = static()
    write_csv(tmp_path / "log.csv", acc, gyr)
    s = columns_settings(tmp_path, accel={"columns": ["ax", "ay", "az"], "units": "m s-2", "sample_kind": "rate"})
    out = importers.import_recording(s, tmp_path / "acc.nc")
    h = recording.validate(out)
    assert h.sensors == ("accel",) and h.absent == ("gyro",) and h.gyro_units is None
    with netCDF4.Dataset(out) as nc:
        assert "gyro" not in nc.variables and nc.getncattr("absent_sensors") == "gyro"
    np.testing.assert_allclose(recording.load(out)["accel"].values, acc, rtol=1e-15, atol=1e-15)
    np.savez(tmp_path / "log.npz", data=np.column_stack([acc, gyr]), columns=np.array(["ax", "ay", "az", "gx", "gy",
                                                                                       "gz"]))
    s = {"format": "npz_columns", "file": "log.npz", "data_dir": str(tmp_path), "sample_rate_hz": FS,
         "latitude_deg": 48.0, "gyro": {"columns": ["gx", "gy", "gz"], "units": "rad s-1", "sample_kind": "rate"}}
    ds = importers.import_dataset(s)
    assert "accel" not in ds and ds.attrs["absent_sensors"] == "accel"
    np.testing.assert_array_equal(ds["gyro"].values, gyr)
    with pytest.raises(ImportDataError, match="neither triad declared"):
        importers.import_dataset(columns_settings(tmp_path))
    # formats whose layout holds both triads still need both declared
    with pytest.raises(ImportDataError, match="triad declaration missing"):
        importers.import_dataset({"format": "mikoff", "file": "log.csv", "data_dir": str(tmp_path),
                                  "sample_rate_hz": FS, "latitude_deg": 48.0,
                                  "accel": {"units": "m s-2", "sample_kind": "rate"}})


def test_a_missing_triad_must_be_declared_absent_in_the_file(tmp_path):
    acc, _ = static(500)
    ds = recording.make_dataset(acc, None, sample_rate_hz=FS, latitude_deg=48.0, accel_units="m s-2",
                                gyro_units=None, source="recorded")
    path = recording.write(ds, tmp_path / "acc.nc")
    with netCDF4.Dataset(path, "a") as nc:
        nc.delncattr("absent_sensors")
    with pytest.raises(RecordingError, match="variable 'gyro'.*variable missing.*absent_sensors"):
        recording.validate(path)
    with netCDF4.Dataset(path, "a") as nc:
        nc.setncattr("absent_sensors", "accel")
    with pytest.raises(RecordingError, match="declared absent"):
        recording.validate(path)
    with netCDF4.Dataset(path, "a") as nc:
        nc.setncattr("absent_sensors", "magnetometer")
    with pytest.raises(RecordingError, match="absent_sensors.*'accel' or 'gyro'"):
        recording.validate(path)


def partial_recording(tmp_path, which, seed=0):
    acc, gyr = static(seed=seed)
    ds = recording.make_dataset(acc if which == "accel" else None, gyr if which == "gyro" else None,
                                sample_rate_hz=FS, latitude_deg=48.0, accel_units="m s-2", gyro_units="rad s-1",
                                source="recorded")
    return recording.write(ds, tmp_path / f"{which}_only.nc")


@pytest.mark.parametrize("which", ["accel", "gyro"])
def test_commands_on_a_partial_record(tmp_path, capsys, which):
    path = partial_recording(tmp_path, which)
    other = "gyro" if which == "accel" else "accel"
    assert cli.main(["validate", str(path)]) == 0
    out = capsys.readouterr().out
    assert f"no {other} (partial record" in out and "plausible" in out
    assert cli.main(["noise", str(path), "--out", str(tmp_path / "noise"), "--bootstrap", "20"]) == 0
    rep = json.loads((tmp_path / "noise" / "noise.json").read_text())
    assert set(rep["sensors"]) == {which} and any(f"no {other} in the record" in n for n in rep["notes"])
    capsys.readouterr()
    for argv in (["diagnose", str(path), "--out", str(tmp_path / "diag")],
                 ["navigate", str(path), "--out", str(tmp_path / "nav.nc")]):
        code = cli.main(argv)
        err = capsys.readouterr().err
        assert code == 2, err
        assert f"variable '{other}'" in err and "holds" in err and "only" in err and "Traceback" not in err
        assert "units" not in err.split("fix")[0]   # the absent triad is named as absent, not as a unit mistake
    assert not (tmp_path / "nav.nc").exists()


def test_a_constant_placeholder_is_named_as_such_not_as_a_unit_mistake(tmp_path, capsys):
    acc, gyr = static()
    ds = recording.make_dataset(acc, np.zeros_like(gyr), sample_rate_hz=FS, latitude_deg=48.0, accel_units="m s-2",
                                gyro_units="rad s-1", source="recorded")
    path = recording.write(ds, tmp_path / "zero_gyro.nc")
    assert cli.main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert "gyro" in err and "constant placeholder" in err and "leave 'gyro' out of the import settings" in err
    assert "Earth's rate" not in err and "sample_kind" not in err
    ds = recording.make_dataset(np.tile([0.0, 0.0, G], (len(gyr), 1)), gyr, sample_rate_hz=FS, latitude_deg=48.0,
                                accel_units="m s-2", gyro_units="rad s-1", source="recorded")
    path = recording.write(ds, tmp_path / "flat_accel.nc")
    assert cli.main(["noise", str(path), "--out", str(tmp_path / "noise"), "--bootstrap", "20"]) == 2
    err = capsys.readouterr().err
    assert "accel" in err and "constant placeholder" in err and "longer static period" not in err
    assert not (tmp_path / "noise").exists()

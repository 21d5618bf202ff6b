"""MATLAB .mat import: v5 files written with scipy.io.savemat, v7.3 files written with h5py the way MATLAB lays
them out (a 512-byte user block holding MATLAB's 128-byte header, arrays stored column-major so that an n x 3
matrix is a (3, n) HDF5 dataset). The samples read back equal the samples written, axis by axis, for every way of
mapping variables (an n x 3 array, struct fields, one vector per axis, columns of a wider array, a 3 x n array)."""
from __future__ import annotations

import math

import h5py
import numpy as np
import pytest
import scipy.io

from calib.ingest import importers
from calib.ingest.common import ImportDataError
from calib.io import recording

FS = 200.0
G = 9.80665
MATLAB_73_HEADER = (b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
                    .ljust(116) + b"\x00" * 8 + b"\x00\x02IM")


def samples(n=2000, seed=0):
    """Static accel (m s-2, z up) and gyro (rad s-1) samples with white noise."""
    rng = np.random.default_rng(seed)
    acc = np.array([0.05, -0.03, G]) + 0.02 * rng.standard_normal((n, 3))
    gyr = np.array([1e-3, -2e-3, 5e-4]) + 1e-3 * rng.standard_normal((n, 3))
    return acc, gyr


def write_v73(path, variables: dict):
    """A MATLAB v7.3 file: HDF5 with MATLAB's header in the user block; each array stored transposed (MATLAB is
    column-major); a dict is a struct (an HDF5 group)."""
    def put(group, name, value):
        if isinstance(value, dict):
            sub = group.create_group(name)
            for k, v in value.items():
                put(sub, k, v)
        else:
            group.create_dataset(name, data=np.atleast_2d(np.asarray(value, dtype=float)).T)

    with h5py.File(path, "w", userblock_size=512) as f:
        for k, v in variables.items():
            put(f, k, v)
    with open(path, "r+b") as fh:
        fh.write(MATLAB_73_HEADER)


def base(tmp_path, file, **over):
    s = {"format": "matlab", "file": file, "data_dir": str(tmp_path), "latitude_deg": 45.0,
         "accel": {"units": "m s-2", "sample_kind": "rate"}, "gyro": {"units": "rad s-1", "sample_kind": "rate"}}
    for k, v in over.items():
        if k in ("accel", "gyro") and v is not None:
            s[k] = {**s[k], **v}
        elif v is None:
            s.pop(k, None)
        else:
            s[k] = v
    return s


@pytest.mark.parametrize("version", ["v5", "v7.3"])
def test_struct_fields_and_time_variable(tmp_path, version):
    acc, gyr = samples()
    t = 12.5 + np.arange(len(acc)) / FS
    content = {"data": {"acc": acc, "gyr": gyr, "t": t}}
    if version == "v5":
        scipy.io.savemat(tmp_path / "rec.mat", content)
    else:
        write_v73(tmp_path / "rec.mat", content)
    s = base(tmp_path, "rec.mat", accel={"variable": "data.acc"}, gyro={"variable": "data.gyr"},
             time={"variable": "data.t", "units": "s"})
    ds = importers.import_dataset(s)
    np.testing.assert_array_equal(ds["accel"].values, acc)
    np.testing.assert_array_equal(ds["gyro"].values, gyr)
    np.testing.assert_allclose(ds["time"].values, t, rtol=0, atol=1e-12)
    assert ds.attrs["sample_rate_hz"] == pytest.approx(FS, rel=1e-9)
    assert ds.attrs["matlab_version"] == ("5/7" if version == "v5" else "7.3 (HDF5)")
    out = importers.import_recording(s, tmp_path / "rec.nc")
    h = recording.validate(out)
    assert h.sensors == ("accel", "gyro") and h.n_samples == len(acc)


@pytest.mark.parametrize("version", ["v5", "v7.3"])
def test_one_vector_per_axis_columns_of_a_wide_array_and_a_transposed_array(tmp_path, version):
    acc, gyr = samples(1500, seed=1)
    wide = np.column_stack([np.arange(len(acc)), gyr[:, 2], gyr[:, 0], gyr[:, 1]])   # time index, gz, gx, gy
    content = {"ax": acc[:, 0], "ay": acc[:, 1], "az": acc[:, 2], "imu": wide, "accT": acc.T, "Fs": FS}
    if version == "v5":
        scipy.io.savemat(tmp_path / "rec.mat", content)
    else:
        write_v73(tmp_path / "rec.mat", content)
    s = base(tmp_path, "rec.mat", accel={"variables": ["ax", "ay", "az"], "sign": [1, -1, -1]},
             gyro={"variable": "imu", "columns": [2, 3, 1]}, sample_rate_variable="Fs")
    ds = importers.import_dataset(s)
    np.testing.assert_array_equal(ds["accel"].values, acc * [1, -1, -1])
    np.testing.assert_array_equal(ds["gyro"].values, gyr)
    assert ds.attrs["sample_rate_hz"] == FS
    # a 3 x n array is read transposed, and says so
    s2 = base(tmp_path, "rec.mat", accel={"variable": "accT"}, gyro=None, sample_rate_hz=FS)
    ds2 = importers.import_dataset(s2)
    np.testing.assert_array_equal(ds2["accel"].values, acc)
    assert "transposed" in ds2.attrs["accel_variable_map"] and "gyro" not in ds2


def test_refusals_name_the_variable_and_what_the_file_holds(tmp_path):
    acc, gyr = samples(500)
    scipy.io.savemat(tmp_path / "rec.mat", {"data": {"acc": acc, "gyr": gyr}, "label": "static"})
    s = base(tmp_path, "rec.mat", accel={"variable": "data.accel"}, gyro={"variable": "data.gyr"}, sample_rate_hz=FS)
    with pytest.raises(ImportDataError) as e:
        importers.import_dataset(s)
    assert "data.accel" in str(e.value) and "data.acc" in str(e.value) and "data.gyr" in str(e.value)
    with pytest.raises(ImportDataError, match="is a struct, not an array"):
        importers.import_dataset(base(tmp_path, "rec.mat", accel={"variable": "data"}, gyro={"variable": "data.gyr"},
                                      sample_rate_hz=FS))
    with pytest.raises(ImportDataError, match="not numbers"):
        importers.import_dataset(base(tmp_path, "rec.mat", accel={"variable": "label"}, gyro={"variable": "data.gyr"},
                                      sample_rate_hz=FS))
    with pytest.raises(ImportDataError, match="sample_rate_hz.*required"):
        importers.import_dataset(base(tmp_path, "rec.mat", accel={"variable": "data.acc"},
                                      gyro={"variable": "data.gyr"}))
    with pytest.raises(ImportDataError, match="unknown key"):
        importers.import_dataset(base(tmp_path, "rec.mat", accel={"variable": "data.acc", "colums": [0, 1, 2]},
                                      gyro={"variable": "data.gyr"}, sample_rate_hz=FS))
    (tmp_path / "text.mat").write_text("1 2 3\n")
    with pytest.raises(ImportDataError, match="not a MATLAB .mat file"):
        importers.import_dataset(base(tmp_path, "text.mat", accel={"variable": "a"}, gyro=None, sample_rate_hz=FS))
    # a wrong unit is caught by the gravity-norm check as for every format
    with pytest.raises(ImportDataError, match="declare accel.units: 'm s-2'"):
        importers.import_dataset(base(tmp_path, "rec.mat", accel={"variable": "data.acc", "units": "g"},
                                      gyro={"variable": "data.gyr"}, sample_rate_hz=FS))


def test_a_plain_hdf5_file_is_read_as_v73(tmp_path):
    acc, _ = samples(400)
    with h5py.File(tmp_path / "plain.mat", "w") as f:
        f.create_dataset("acc", data=acc.T)
    ds = importers.import_dataset(base(tmp_path, "plain.mat", accel={"variable": "acc"}, gyro=None,
                                       sample_rate_hz=FS))
    np.testing.assert_array_equal(ds["accel"].values, acc)
    assert math.isclose(ds.attrs["sample_rate_hz"], FS)

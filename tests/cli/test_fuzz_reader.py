"""Fuzzing the recording reader (hypothesis): a truncated file, flipped bytes or NaN samples give either a
valid recording or an InputError (exit 2 of ``calib validate``) -- never another exception, never a traceback.

The seed file is a short stationary session from the simulator, written once per module."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from calib import cli
from calib.core.errors import InputError
from calib.io import recording
from calib.io.netcdf import write_netcdf
from calib.sim.static_session import simulate_static_session

FUZZ = settings(max_examples=40, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@pytest.fixture(scope="module")
def seed_file(tmp_path_factory):
    """A valid recording with an explicit time coordinate (30 s at 100 Hz, physical increments)."""
    folder = tmp_path_factory.mktemp("fuzz")
    long_form = simulate_static_session({"mode": "physical", "duration_h": 30.0 / 3600.0,
                                         "site": {"latitude_deg": 30.58}}, 5, folder / "long.nc")
    ds = recording.load(long_form)
    del ds.attrs["_path"]
    return recording.write(ds, folder / "seed.nc")


def outcome(path):
    """'ok' or 'refused' for every reader entry point and for ``calib validate``; anything else fails."""
    results = set()
    for fn in (recording.read_header, recording.validate, recording.load):
        try:
            fn(path)
            results.add("ok")
        except InputError as exc:
            assert str(path) in str(exc)
            results.add("refused")
    code = cli.main(["validate", str(path)])
    assert code in (0, 2)
    return results, code


@FUZZ
@given(keep=st.floats(min_value=0.0, max_value=0.999))
def test_truncated_file_is_always_refused(seed_file, tmp_path_factory, capsys, keep):
    blob = Path(seed_file).read_bytes()
    path = tmp_path_factory.mktemp("cut") / "cut.nc"
    path.write_bytes(blob[:int(len(blob) * keep)])
    results, code = outcome(path)
    assert results == {"refused"} and code == 2
    assert "Traceback" not in capsys.readouterr().err


@FUZZ
@given(flips=st.lists(st.tuples(st.floats(min_value=0.0, max_value=1.0, exclude_max=True),
                                st.integers(min_value=0, max_value=255)), min_size=1, max_size=40))
def test_flipped_bytes_give_a_recording_or_a_refusal(seed_file, tmp_path_factory, capsys, flips):
    blob = bytearray(Path(seed_file).read_bytes())
    for where, value in flips:
        blob[int(where * len(blob))] = value
    path = tmp_path_factory.mktemp("flip") / "flip.nc"
    path.write_bytes(bytes(blob))
    outcome(path)
    assert "Traceback" not in capsys.readouterr().err
    assert [p for p in os.listdir(path.parent) if p != "flip.nc"] == []


@FUZZ
@given(data=st.data())
def test_nan_samples_are_refused_by_index(seed_file, tmp_path_factory, capsys, data):
    ds = recording.load(seed_file)
    del ds.attrs["_path"]
    n = ds.sizes["time"]
    var = data.draw(st.sampled_from(["accel", "gyro", "time"]))
    idx = sorted(data.draw(st.sets(st.integers(min_value=0, max_value=n - 1), min_size=1, max_size=5)))
    bad = data.draw(st.sampled_from([np.nan, np.inf, -np.inf]))
    if var == "time":
        t = ds["time"].values.copy()
        t[idx] = bad
        ds = ds.assign_coords(time=("time", t, ds["time"].attrs))
    else:
        v = ds[var].values.copy()
        v[idx, data.draw(st.integers(min_value=0, max_value=2))] = bad
        ds[var] = (ds[var].dims, v, ds[var].attrs)
    path = write_netcdf(ds, tmp_path_factory.mktemp("nan") / "nan.nc")
    with pytest.raises(InputError) as ei:
        recording.validate(path)
    if var != "time":
        assert f"NaN or Inf at sample {idx[0]}" in str(ei.value)
    assert cli.main(["validate", str(path)]) == 2
    assert "Traceback" not in capsys.readouterr().err

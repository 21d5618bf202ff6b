"""The importers' registry (a format is one module and one entry) and where the data files are looked for
(settings' data_dir, a workflow's data_root, $CALIB_DATA, the shared data folder beside the repository)."""
from __future__ import annotations

import importlib
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
import yaml

import calib.ingest
from calib.ingest import common, importers
from calib.ingest.common import ImportDataError

ROOT = Path(__file__).resolve().parents[2]
ROWS = np.array([[0.1, -0.2, 9.8, 0.01, -0.02, 0.03]]) + np.arange(50)[:, None] * 1e-4


def _mikoff_settings(**over):
    s = {"format": "mikoff", "file": "unit/imu.log", "sample_rate_hz": 100, "latitude_deg": 45.0,
         "accel": {"units": "m s-2", "sample_kind": "rate"}, "gyro": {"units": "rad s-1", "sample_kind": "rate"}}
    s.update(over)
    return s


def _write_log(folder: Path) -> Path:
    p = folder / "unit" / "imu.log"
    p.parent.mkdir(parents=True)
    p.write_text("".join(" ".join(f"{v:.6f}" for v in r) + "\n" for r in ROWS))
    return p


def test_package_exports_the_dispatch():
    assert calib.ingest.import_recording is importers.import_recording
    assert calib.ingest.import_dataset is importers.import_dataset
    assert calib.ingest.load_settings is common.load_settings


def test_each_registered_format_module_declares_its_keys():
    assert importers.FORMATS == tuple(importers.IMPORTERS)
    for fmt, fn in importers.IMPORTERS.items():
        mod = importlib.import_module(fn.__module__)
        assert fn.__name__ == f"import_{fmt}" and isinstance(mod.KEYS, set) and not mod.KEYS & common.COMMON_KEYS


def test_a_key_of_another_format_is_refused(tmp_path):
    _write_log(tmp_path)
    s = _mikoff_settings(data_dir=str(tmp_path), files={"accel": "a", "gyro": "g"})  # an imu_tk key
    with pytest.raises(ImportDataError, match="unknown key for format 'mikoff'"):
        importers.import_dataset(s)


def test_a_new_format_is_one_entry(monkeypatch):
    seen = []

    def import_fake(settings):
        seen.append(settings["format"])
        return xr.Dataset()

    monkeypatch.setitem(importers.IMPORTERS, "fake", import_fake)
    assert isinstance(importers.import_dataset({"format": "fake"}), xr.Dataset) and seen == ["fake"]
    with pytest.raises(ImportDataError, match="one of: .*mikoff.*fake"):
        importers.import_dataset({"format": "nope"})


def test_default_data_root_is_the_shared_folder_or_calib_data(monkeypatch, tmp_path):
    monkeypatch.delenv("CALIB_DATA", raising=False)
    assert common.default_data_root() == (ROOT.parent / "shared" / "data").resolve()
    monkeypatch.setenv("CALIB_DATA", str(tmp_path))
    assert common.default_data_root() == tmp_path


def test_data_dir_then_data_root_then_calib_data(monkeypatch, tmp_path):
    env, root, own = tmp_path / "env", tmp_path / "root", tmp_path / "own"
    monkeypatch.setenv("CALIB_DATA", str(env))
    cfg = tmp_path / "settings.yaml"
    cfg.write_text(yaml.safe_dump(_mikoff_settings()))
    assert common.data_dir(common.load_settings(cfg)) == env
    assert common.data_dir(common.load_settings(cfg, data_root=root)) == root
    cfg.write_text(yaml.safe_dump(_mikoff_settings(data_dir="own")))  # relative to the settings file
    assert common.data_dir(common.load_settings(cfg, data_root=root)).resolve() == own


@pytest.mark.parametrize("how", ["data_root", "CALIB_DATA"])
def test_import_finds_the_file_under_the_data_root(monkeypatch, tmp_path, how):
    data = tmp_path / "elsewhere"
    data.mkdir()
    log = _write_log(data)
    cfg = tmp_path / "settings.yaml"
    cfg.write_text(yaml.safe_dump(_mikoff_settings()))
    monkeypatch.setenv("CALIB_DATA", str(data if how == "CALIB_DATA" else tmp_path / "missing"))
    s = common.load_settings(cfg, data_root=data if how == "data_root" else None)
    ds = importers.import_dataset(s)
    np.testing.assert_array_equal(ds["accel"].values, np.loadtxt(log)[:, :3])
    np.testing.assert_array_equal(ds["gyro"].values, np.loadtxt(log)[:, 3:])
    assert ds.attrs["source_files"] == "unit/imu.log"  # relative to the data root: machine independent
    monkeypatch.setenv("CALIB_DATA", str(tmp_path / "missing"))
    with pytest.raises(ImportDataError, match="input file not found"):
        importers.import_dataset(common.load_settings(cfg))

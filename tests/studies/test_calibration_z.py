"""The z-score study of the default calibration (``calibration.run_z_seeds``): the in-memory, parallel path gives
the same numbers, to the last bit, as the reference path that writes every seed's recordings to files and reads
them back, serially; and its in-memory recordings are the files' datasets."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from calib.core.triad import PARAM_NAMES
from calib.io import recording
from calib.sim.calibration_session import (build_calibration_simulator, calibration_session_channels,
                                           calibration_session_dataset)
from calib.sim.static_session import static_counts_dataset
from calib.sim.truth import calibration_truth
from calib.studies import calibration as cs
from calib.studies import stages

SITE = {"latitude_deg": 30.58, "height_m": 0.0}

ROOT = Path(__file__).resolve().parents[2]
#: a short session (24 positions of 10 s, one revolution per rotation window) of the default unit and noise
SESSION = {"sample_rate_hz": 100.0, "dwell_s": 10.0, "revolutions": 1}
#: a 12 min static record per seed (Allan taus up to 6 min: enough points above noise_tau_min_s for the fit)
CHECK = {"duration_h": 0.2, "attitude_deg": {"pitch": 0.0, "roll": 0.0, "yaw": 0.0}}


@pytest.fixture(scope="module")
def ccfg():
    c = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())["calibration"]
    return {**c, "NP": 30, "EG": 200, "noise_record": "static_check", "z_noise_record": "per_seed"}


def _run(tmp_path, name, ccfg, n, **kw):
    out = tmp_path / name
    m = cs.run_z_seeds(SESSION, SITE, ccfg, n, 4242, out / "z.csv", out / "z.png", out / "z.json", out / "work",
                       log=lambda *a: None, check=CHECK, **kw)
    return (out / "z.csv").read_text(), (out / "z.json").read_text(), m


def test_parallel_in_memory_equals_serial_file_path(tmp_path, ccfg):
    ref = _run(tmp_path, "files", ccfg, 3, files=True, workers=1)
    mem = _run(tmp_path, "memory", ccfg, 3, workers=1)
    par = _run(tmp_path, "parallel", ccfg, 3, workers=2)
    assert mem[0] == ref[0] and par[0] == ref[0]  # the CSV, byte for byte
    assert mem[1] == ref[1] and par[1] == ref[1]  # the metrics (full float repr), byte for byte
    z = json.loads(ref[1])["z"]
    assert len(z) == 9 + 12 and all(np.isfinite(v["mean_z"]) for v in z.values())
    # beside every parameter: the spread of the estimates, the Cramér–Rao bound and their ratio (3 seeds: loose)
    assert all(v["sigma_crb"] > 0 and v["std_estimate"] > 0 for v in z.values())
    assert all(v["efficiency_ratio"] == pytest.approx(v["std_estimate"] / v["sigma_crb"]) for v in z.values())
    header = ref[0].splitlines()[0].split(",")
    assert header[-4:] == ["std_estimate", "sigma_crb", "efficiency_ratio", "efficiency_note"]
    # the paper's 12 accelerometer parameters from the norm: K and E have no bound (the triad's rotation), b has
    crb = json.loads(ref[1])["crb"]
    assert [n for n, v in crb["accel_paper12"]["sigma"].items() if v is None] == list(PARAM_NAMES[:9])
    assert "not determined: Kx Ky Kz Exy Exz Eyx Eyz Ezx Ezy" in ref[0]
    # no scratch folder is left behind: the reference path removes its recordings and their folder, the in-memory
    # path makes none (an empty tmp_zscores stayed in the study's results/calibration)
    assert not (tmp_path / "files" / "work").exists() and not (tmp_path / "memory" / "work").exists()
    assert not (tmp_path / "parallel" / "work").exists()


def test_parallel_equals_serial_without_noise_record(tmp_path, ccfg):
    c = {**ccfg, "noise_record": "none"}
    ser = _run(tmp_path, "serial", c, 3, workers=1)
    par = _run(tmp_path, "parallel", c, 3, workers=3)
    ref = _run(tmp_path, "files", c, 2, files=True)
    two = _run(tmp_path, "two", c, 2, workers=2)
    assert ser[:2] == par[:2] and ref[:2] == two[:2]
    assert "segment_sigma" not in ser[0] and ser[2]["noise_record"] == "none"


def test_in_memory_recordings_are_the_loaded_files(tmp_path):
    """What the study feeds ``segments.extract`` and the noise fit is the dataset ``recording.load`` returns for the
    files the data stage writes: same variables, dtypes, samples and attributes (only the file's provenance
    attributes are absent); the seed-independent parts come from a simulator of another seed."""
    cfg = stages.calibration_cfg(SESSION, SITE)
    stages.simulate_calibration(SESSION, SITE, 77, tmp_path / "s.nc", tmp_path / "s.truth.json")
    loaded = recording.load(tmp_path / "s.nc")
    sim = build_calibration_simulator(cfg, 5)  # another seed: only the noise depends on it
    mem = cs._as_loaded(calibration_session_dataset(sim, 77, sim.clean_increments(),
                                                    calibration_session_channels(sim)),
                        tmp_path / "s.nc")
    _assert_same_recording(mem, loaded, ignore_attrs={"calib_version", "git_commit", "made_by_rule", "seed",
                                                      "config_hash"})
    truth = json.loads((tmp_path / "s.truth.json").read_text())
    mine = json.loads(json.dumps(calibration_truth(build_calibration_simulator(cfg, 77))))
    truth.pop("generation_time_s")
    mine.pop("generation_time_s")
    assert mine == truth

    scfg = stages.static_check_cfg(CHECK, SESSION, SITE)
    stages.simulate_static_check(CHECK, SESSION, SITE, 88, tmp_path / "l.nc", tmp_path / "l.truth.json")
    loaded = recording.load(tmp_path / "l.nc")
    mem = static_counts_dataset(scfg, 88, path=tmp_path / "l.nc")
    _assert_same_recording(mem, loaded)


def _assert_same_recording(a, b, ignore_attrs=frozenset()):
    assert sorted(a.variables) == sorted(b.variables)
    for v in a.variables:
        assert a[v].dtype == b[v].dtype and a[v].dims == b[v].dims, v
        np.testing.assert_array_equal(a[v].values, b[v].values, err_msg=v)
        assert a[v].attrs == b[v].attrs, v
    ka, kb = set(a.attrs), set(b.attrs) - set(ignore_attrs)
    assert ka == kb
    for k in ka:
        assert type(a.attrs[k]) is type(b.attrs[k]) and np.array_equal(a.attrs[k], b.attrs[k]), k


def test_efficiency_note_only_above_two_and_says_what_is_left_out():
    """A ratio above 2 on a determined parameter gets the information the estimator leaves out; none otherwise."""
    assert cs.efficiency_note("gyro", "bx", 1.9) == ""
    assert cs.efficiency_note("gyro", "bx", float("nan")) == ""
    assert "Gauss-Markov bias between windows" in cs.efficiency_note("gyro", "bx", 2.5)
    assert "unweighted" in cs.efficiency_note("accel", "Eyx", 3.0)
    assert "," not in "".join(cs.efficiency_note(s, n, 3.0) for s in ("accel", "gyro") for n in ("Kx", "Exy", "bx"))


def test_blocks_with_different_bounds_are_refused():
    """Every block computes the session's bound from its first seed; blocks of different sessions are refused."""
    a = {"accel": {"sigma": {"Kx": 1.0}}}
    assert cs._one_bound([a, None, dict(a)]) == a
    with pytest.raises(ValueError, match="bounds differ"):
        cs._one_bound([a, {"accel": {"sigma": {"Kx": 2.0}}}])
    with pytest.raises(ValueError, match="no Cram"):
        cs._one_bound([None, None])

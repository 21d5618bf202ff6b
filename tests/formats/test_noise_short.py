"""``calib noise`` on short records: it states the tau range a record supports and the terms it cannot estimate,
every interval holds its own estimate strictly inside (also on a record with a dropout step, where the model
does not fit), and a gyro-only 60 s record written in the test as a MATLAB v7.3 file (h5py, MATLAB's layout) goes
through import -> validate -> noise with the known white-noise density inside its interval. The samples are drawn
from the definitions (white rate noise of density N: std N sqrt(fs) per sample), not by the bootstrap under test."""
from __future__ import annotations

import json
import math

import h5py
import numpy as np
import pytest
import yaml

from calib import cli
from calib.signal import allan, ieee952

N_TRUE = 3.5e-4   # rad s-1 / sqrt(Hz)
MATLAB_73_HEADER = (b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
                    .ljust(116) + b"\x00" * 8 + b"\x00\x02IM")


def white(seed, n, fs, N=N_TRUE, bias=(0.0, 0.0, 0.0)):
    rng = np.random.default_rng(seed)
    return N * math.sqrt(fs) * rng.standard_normal((n, 3)) + np.asarray(bias)


def inside(nt: ieee952.NoiseTerms):
    """(term, axis, value, lo, hi) of every estimate not strictly inside its interval (an unresolved term fitted
    to 0 has the interval [0, bound]: 0 is its lower end by definition)."""
    out = []
    for t in ieee952.TERMS:
        rows = [(i, nt.values[t][i], nt.lo[t][i], nt.hi[t][i]) for i in range(len(nt.axes))]
        rows.append(("rms", *nt.combined[t][:3]))
        for ax, v, lo, hi in rows:
            ok = (lo < v < hi) or (v == 0.0 and lo == 0.0 and hi > 0.0)
            if not ok:
                out.append((t, ax, v, lo, hi))
    return out


@pytest.mark.parametrize("fs,step,seed", [(100.0, 0.0, 1), (400.0, 1e-2, 0), (100.0, 1e-2, 1), (100.0, 1e-3, 0)])
def test_every_estimate_lies_strictly_inside_its_interval_on_a_60_s_record(fs, step, seed):
    """White noise, and white noise whose last 239 (or 50) samples are a logger's all-zero dropout (a step of the
    gyro bias): on the two records with a 0.01 rad/s step the old intervals left their own estimate on an end or
    outside (the band's bound of an unresolved random walk below its fit: "8.066e-05 [0, 8.066e-05]"; a flicker
    floor's replicates all below the fit: "0.0004137 [0.0004162, 0.0004489]")."""
    n = int(60 * fs)
    y = white(seed, n, fs, N=3.5e-5, bias=(step, step, step))   # the density of a tactical-grade MEMS gyro
    if step:
        y[-(239 if fs == 400.0 else 50):] = 0.0
    nt = ieee952.noise_terms(y, fs, n_boot=100, seed=0, unit="rad s-1")
    assert inside(nt) == []
    if step >= 1e-2:   # a step is not stationary noise: the report says the model does not fit
        assert nt.model_misfit() and any("fitted model leaves" in s for s in nt.short_record_notes())
    if step == 0.0:
        assert not nt.model_misfit()


def test_log_basic_interval_estimate_is_its_centre():
    reps = np.linspace(1.1, 1.3, 201)[:, None]     # replicates all above the fit 1.0: the fit is biased low
    est, lo, hi, ok = ieee952.log_basic_interval(np.array([1.0]), reps, 0.95, np.array([5.0]))
    assert ok[0] and lo[0] < est[0] < hi[0] < 1.0 and est[0] == pytest.approx(1.0 / 1.2)
    reps0 = np.concatenate([np.zeros(100), np.linspace(0.0, 2.0, 101)])[:, None]   # not told from zero
    est, lo, hi, ok = ieee952.log_basic_interval(np.array([0.8]), reps0, 0.95, np.array([0.5]))
    assert not ok[0] and lo[0] == 0.0 and est[0] == 0.8 and hi[0] == pytest.approx(1.6)


def test_bootstrap_flicker_has_the_law_up_to_half_the_record():
    fs, n, B = 100.0, 6000, 1e-3
    vals = {"Q": np.zeros(1), "N": np.zeros(1), "B": np.full(1, B), "K": np.zeros(1)}
    theta = ieee952.simulate_phase(vals, n, fs, 200, np.random.default_rng(0))
    ms = allan.octave_clusters(n)[2:]   # from 4 samples (the discrete flicker's first points lie above the law)
    tau = ms / fs
    av = ieee952.second_difference_sums(theta, ms) / (2 * tau[:, None] ** 2 * ((n + 1) - 2 * ms)[:, None])
    ratio = np.sqrt(av.mean(axis=1)) / (ieee952.FLOOR * B)
    np.testing.assert_allclose(ratio, 1.0, atol=0.06)   # one record length synthesised: 0.78 at tau = T / 2


def write_v73(path, variables):
    with h5py.File(path, "w", userblock_size=512) as f:
        for k, v in variables.items():
            f.create_dataset(k, data=np.atleast_2d(np.asarray(v, dtype=float)))   # a row vector, MATLAB's layout
    with open(path, "r+b") as fh:
        fh.write(MATLAB_73_HEADER)


def test_gyro_only_60_s_mat_record_through_import_validate_noise(tmp_path, capsys):
    fs = 200.0
    n = int(60 * fs)
    gyr = white(7, n, fs, bias=(0.01, -0.02, 0.005))
    write_v73(tmp_path / "gyro.mat", {"gx": gyr[:, 0], "gy": gyr[:, 1], "gz": gyr[:, 2], "t": np.arange(n) / fs})
    settings = {"format": "matlab", "file": "gyro.mat", "data_dir": ".", "time": {"variable": "t", "units": "s"},
                "latitude_deg": 45.0, "gyro": {"variables": ["gx", "gy", "gz"], "units": "rad s-1",
                                               "sample_kind": "rate"}}
    (tmp_path / "gyro.yaml").write_text(yaml.safe_dump(settings))
    rec, out = tmp_path / "gyro.nc", tmp_path / "noise"
    assert cli.main(["import", str(tmp_path / "gyro.yaml"), str(rec)]) == 0
    assert cli.main(["validate", str(rec)]) == 0
    assert "no accel (partial record" in capsys.readouterr().out
    assert cli.main(["noise", str(rec), "--out", str(out), "--bootstrap", "100"]) == 0
    err = capsys.readouterr().err
    assert "tau = 0.005 .. 30 s" in err and "rate random walk K not estimated" in err
    rep = json.loads((out / "noise.json").read_text())
    assert set(rep["sensors"]) == {"gyro"} and rep["kalibr"] is None
    g = rep["sensors"]["gyro"]
    assert g["tau_range_s"] == [pytest.approx(1 / fs), pytest.approx(30.0)]
    assert {"B", "K"} <= set(g["not_estimated"]) and "N" not in g["not_estimated"]
    comb = g["terms"]["N"]["combined_rms"]
    assert comb["resolved"] and comb["lo"] < N_TRUE < comb["hi"] and comb["lo"] < comb["value"] < comb["hi"]
    for ax in "xyz":
        a = g["terms"]["N"]["axes"][ax]
        assert a["lo"] < a["value"] < a["hi"]
    md = (out / "noise.md").read_text()
    assert "no accel in the record" in md and "bias instability B not estimated" in md
    # Kalibr's file needs both triads: refused by name, nothing written
    assert cli.main(["noise", str(rec), "--out", str(tmp_path / "n2"), "--kalibr", str(tmp_path / "imu.yaml"),
                     "--topic", "/imu"]) == 2
    assert "needs the noise of both triads" in capsys.readouterr().err and not (tmp_path / "imu.yaml").exists()

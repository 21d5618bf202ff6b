"""Noise terms of a static record: allantools is the oracle for the Allan deviation, its degrees of freedom and
its chi-square intervals; the fitted IEEE-952 terms are checked against the simulated truth: over 50 seeds of
white noise + a random walk the true N and K (per axis, and the RMS over the axes that goes to Kalibr) fall inside
the stated 95 % intervals at the claimed rate; ``calib noise --kalibr`` writes Kalibr's keys with those values."""
from __future__ import annotations

import json
import math

import allantools
import numpy as np
import pytest
import yaml

from calib.io import recording
from calib.signal import allan, ieee952

from conftest import calib

FS = 50.0
N_TRUE = 1e-3      # white rate noise density [unit s^1/2]
K_TRUE = 3.5e-4    # rate random walk [unit s^-1/2]: crosses the white noise at tau = sqrt(3) N / K = 5 s


def white_plus_walk(seed, n, fs=FS, N=N_TRUE, K=K_TRUE, naxes=3):
    """Rate samples of white noise of density N plus a random walk of density K, written out from the
    definitions: white std N sqrt(fs) per sample, walk steps of K / sqrt(fs)."""
    rng = np.random.default_rng(seed)
    white = N * math.sqrt(fs) * rng.standard_normal((n, naxes))
    walk = np.cumsum(K / math.sqrt(fs) * rng.standard_normal((n, naxes)), axis=0)
    return white + walk


def test_allan_deviation_and_intervals_match_allantools():
    y = white_plus_walk(0, 20_000)
    res = allan.adev(y, FS)
    for ax in range(3):
        taus, dev, _, ns = allantools.oadev(y[:, ax], rate=FS, data_type="freq", taus=res.tau)
        np.testing.assert_allclose(taus, res.tau, rtol=1e-12)
        np.testing.assert_allclose(dev, res.adev[:, ax], rtol=1e-9)
    ms = np.rint(res.tau * FS).astype(int)
    n_phase = len(y) + 1
    for alpha in (2, 1, 0, -1, -2):
        ours = ieee952.edf_simple(n_phase, ms, alpha)
        ref = np.array([allantools.edf_simple(n_phase, m, alpha) for m in ms])
        np.testing.assert_allclose(ours, np.maximum(ref, 1.0), rtol=1e-12)
    edf = ieee952.edf_simple(n_phase, ms, -2)
    lo, hi = ieee952.chi2_band(res.adev[:, 0], edf, 0.95)
    for j in range(len(ms)):
        rl, rh = allantools.confidence_interval(res.adev[j, 0], edf[j], ci=0.95)
        assert lo[j] == pytest.approx(rl, rel=1e-12) and hi[j] == pytest.approx(rh, rel=1e-12)


def test_bootstrap_simulator_has_the_ieee952_allan_laws():
    """The replicates of the bootstrap follow eq. (1) of IEEE 952 Annex C term by term (allantools' ADEV)."""
    rng = np.random.default_rng(1)
    n, Q, N, B, K = 2**16, 2e-4, 1e-3, 2e-3, 1e-4
    one = {"Q": np.zeros(1), "N": np.zeros(1), "B": np.zeros(1), "K": np.zeros(1)}
    for term, value, law in (("Q", Q, lambda t: math.sqrt(3) * Q / t), ("N", N, lambda t: N / np.sqrt(t)),
                             ("B", B, lambda t: ieee952.FLOOR * B + 0 * t), ("K", K, lambda t: K * np.sqrt(t / 3))):
        vals = {**one, term: np.full(1, value)}
        theta = ieee952.simulate_phase(vals, n, FS, 8, rng)   # 8 replicates
        taus = np.array([0.2, 1.0, 5.0, 20.0]) if term != "B" else np.array([1.0, 5.0, 20.0])
        dev = np.mean([allantools.oadev(theta[:, r], rate=FS, data_type="phase", taus=taus)[1] ** 2
                       for r in range(8)], axis=0) ** 0.5
        np.testing.assert_allclose(dev, law(taus), rtol=0.12 if term == "B" else 0.08, err_msg=term)


def test_intervals_cover_the_truth_at_the_claimed_rate():
    seeds, n = range(50), 8192   # 164 s at 50 Hz: N and K both resolved, K from few long-tau points
    hit = {"N": 0, "K": 0, "kalibr_N": 0, "kalibr_K": 0}
    trials = 0
    for seed in seeds:
        y = white_plus_walk(seed, n)
        nt = ieee952.noise_terms(y, FS, n_boot=200, seed=seed, unit="rad s-1")
        for t, true in (("N", N_TRUE), ("K", K_TRUE)):
            hit[t] += int(np.sum((nt.lo[t] <= true) & (true <= nt.hi[t])))
        kal = ieee952.kalibr_parameters(nt, nt)   # the same triad as "gyro" and "accel": combined values
        for key, t, true in (("gyroscope_noise_density", "kalibr_N", N_TRUE),
                             ("gyroscope_random_walk", "kalibr_K", K_TRUE)):
            p = kal[key]
            hit[t] += int(p["lo"] <= true <= p["hi"])
            assert p["lo"] <= p["value"] <= p["hi"]
        trials += 3
    cover = {"N": hit["N"] / trials, "K": hit["K"] / trials, "kalibr_N": hit["kalibr_N"] / len(seeds),
             "kalibr_K": hit["kalibr_K"] / len(seeds)}
    print("coverage of the 95 % intervals:", cover)
    assert all(c >= 0.90 for c in cover.values()), cover


def test_unresolved_term_gets_an_upper_bound():
    y = white_plus_walk(3, 8192, K=0.0)   # white noise only: no random walk to see
    nt = ieee952.noise_terms(y, FS, n_boot=60, seed=0)
    for ax in range(3):
        assert not nt.resolved["K"][ax] and nt.lo["K"][ax] == 0.0 and nt.hi["K"][ax] > 0.0
        # the bound is what the band allows: the K line below the band's upper edge at every tau
        assert np.all(nt.hi["K"][ax] * np.sqrt(nt.allan.tau / 3) <= nt.band_hi[:, ax] * (1 + 1e-12))
    np.testing.assert_allclose(nt.values["N"], N_TRUE, rtol=0.03)   # 8192 samples: N to about 1 %


def test_cli_noise_writes_report_figure_and_kalibr_yaml(tmp_path):
    fs, n = 100.0, 16384
    gyr = white_plus_walk(11, n, fs=fs, N=2e-3, K=5e-4)             # rad s-1
    acc = white_plus_walk(12, n, fs=fs, N=3e-3, K=1e-3) + [0.0, 0.0, 9.81]   # m s-2
    ds = recording.make_dataset(acc, gyr, sample_rate_hz=fs, latitude_deg=48.0, accel_units="m s-2",
                                gyro_units="rad s-1", source="synthetic")
    rec = recording.write(ds, tmp_path / "static.nc")
    r = calib("noise", rec, "--out", tmp_path / "noise", "--kalibr", tmp_path / "imu.yaml", "--topic", "/imu0",
              "--bootstrap", "100")
    assert r.returncode == 0, r.stderr
    text = (tmp_path / "imu.yaml").read_text()
    kal = yaml.safe_load(text)
    assert set(kal) == {"accelerometer_noise_density", "accelerometer_random_walk", "gyroscope_noise_density",
                        "gyroscope_random_walk", "rostopic", "update_rate"}
    assert kal["rostopic"] == "/imu0" and kal["update_rate"] == 100.0
    assert "inflate" in text and "m/s^3/sqrt(Hz)" in text and "rad/s/sqrt(Hz)" in text
    rep = json.loads((tmp_path / "noise" / "noise.json").read_text())
    truth = {"gyroscope_noise_density": 2e-3, "gyroscope_random_walk": 5e-4,
             "accelerometer_noise_density": 3e-3, "accelerometer_random_walk": 1e-3}
    for key, true in truth.items():
        p = rep["kalibr"][key]
        assert p["value"] == pytest.approx(kal[key], rel=1e-8)
        assert p["lo"] <= true <= p["hi"], (key, p)
    for name in ("noise.md", "allan.svg", "allan.png"):
        assert (tmp_path / "noise" / name).stat().st_size > 0
    md = (tmp_path / "noise" / "noise.md").read_text()
    assert "rate unit x s^1/2 = rate unit / sqrt(Hz)" in md and "| N | rad s-1 s^1/2 |" in md
    # counts cannot go to Kalibr: refused (exit 2) without a traceback
    ds2 = recording.make_dataset(acc * 1000, gyr * 1000, sample_rate_hz=fs, latitude_deg=48.0, accel_units="count",
                                 gyro_units="count", source="synthetic")
    rec2 = recording.write(ds2, tmp_path / "counts.nc")
    r = calib("noise", rec2, "--out", tmp_path / "n2", "--kalibr", tmp_path / "imu2.yaml", "--topic", "/imu",
              "--bootstrap", "20", "--force")
    assert r.returncode == 2 and "Kalibr needs SI rates" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "imu2.yaml").exists()


def test_calib_noise_interrupted_at_its_last_figure_leaves_the_earlier_products_whole(tmp_path, capsys, monkeypatch):
    """calib noise's report, figures and Kalibr file are one set: an interrupt while the last figure is written
    leaves the earlier run's files as they were and none of this run's."""
    from calib import cli
    from calib.figures import style

    fs = 100.0
    gyr = white_plus_walk(21, 8192, fs=fs)
    acc = white_plus_walk(22, 8192, fs=fs) + [0.0, 0.0, 9.81]
    ds = recording.make_dataset(acc, gyr, sample_rate_hz=fs, latitude_deg=48.0, accel_units="m s-2",
                                gyro_units="rad s-1", source="synthetic")
    rec = recording.write(ds, tmp_path / "static.nc")
    out = tmp_path / "noise"
    out.mkdir()
    earlier = {"noise.json": "{}\n", "noise.md": "earlier\n", "allan.svg": "<svg/>"}
    for name, text in earlier.items():
        (out / name).write_text(text)
    save = style.save

    def interrupted_at_png(fig, path):
        if str(path).endswith(".png"):
            style.plt.close(fig)
            raise KeyboardInterrupt
        return save(fig, path)

    monkeypatch.setattr(style, "save", interrupted_at_png)
    code = cli.main(["noise", str(rec), "--out", str(out), "--kalibr", str(tmp_path / "imu.yaml"), "--topic", "/imu",
                     "--bootstrap", "20"])
    err = capsys.readouterr().err
    assert code == 130 and "interrupted by SIGINT" in err
    assert {p.name: p.read_text() for p in out.iterdir()} == earlier
    assert not (tmp_path / "imu.yaml").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["noise", "static.nc"]

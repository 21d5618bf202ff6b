"""The sample clock fitted to arrival stamps (calib.signal.clock): rate, drops, gaps, jitter."""
import numpy as np
import pytest

from calib.signal.clock import ClockError, fit_clock


def burst_stamps(n, fs, seed, drop=0.01, long=1.024, every=40, noise=0.0):
    """Arrival stamps of a burst logger: steps of ``long`` x the period, a short step every ``every`` samples (the
    mean step is the period), ``drop`` of the samples lost. Returns stamps and their true sample numbers."""
    rng = np.random.default_rng(seed)
    T = 1.0 / fs
    i = np.arange(n)
    t = 5.0 + i * T + (long - 1.0) * T * ((i + rng.integers(every)) % every) + noise * T * rng.standard_normal(n)
    keep = rng.random(n) >= drop
    keep[0] = keep[-1] = True
    return t[keep], i[keep]


@pytest.mark.parametrize("seed", range(6))
def test_burst_arrival_with_drops(seed):
    fs = 100.0 * (1 + 2e-4 * np.random.default_rng(seed).standard_normal())
    t, i = burst_stamps(20_000, fs, seed)
    c = fit_clock(t)
    np.testing.assert_array_equal(c.index - c.index[0], i - i[0])  # every drop counted and located
    assert c.n_dropped == int(np.sum(np.diff(i) - 1))
    assert abs(c.rate_hz - fs) <= 3 * c.rate_std_hz
    assert c.rate_std_hz < 1e-6 * fs
    # the median step is 1.024 periods: 2.4 % low as a rate
    assert c.median_step_rate_hz / fs == pytest.approx(1 / 1.024, rel=1e-6)
    assert not c.gaps and c.largest_step_s > 2 / fs


@pytest.mark.parametrize("seed", range(4))
def test_gaussian_jitter_with_drops(seed):
    rng = np.random.default_rng(50 + seed)
    fs, n = 200.0, 20_000
    i = np.arange(n)
    t = i / fs + 0.1 / fs * rng.standard_normal(n)
    keep = rng.random(n) >= 0.01
    keep[0] = True
    c = fit_clock(t[keep])
    np.testing.assert_array_equal(c.index, i[keep])
    assert abs(c.rate_hz - fs) <= 3 * c.rate_std_hz
    assert c.jitter_std_s == pytest.approx(0.1 / fs, rel=0.05)


@pytest.mark.parametrize("fs", [100.0, 102.4, 204.8, 1 / 0.007])
def test_uniform_stamps_give_the_rate(fs):
    c = fit_clock(np.arange(30_000) / fs)
    assert c.rate_hz == pytest.approx(fs, rel=1e-12)
    assert c.uniform and c.n_dropped == 0 and np.all(c.steps() == 1)


def test_gaps_are_split_and_reported():
    fs = 100.0
    t = np.concatenate([np.arange(1000) / fs, 30.0 + np.arange(1000) / fs,  # 20 s gap
                        40.0 + 0.0046 + np.arange(1000) / fs])             # 0.46 periods off the grid
    c = fit_clock(t)
    assert [j for j, _ in c.gaps] == [999, 1999]
    assert c.gaps[0][1] == pytest.approx(20.01)
    assert c.rate_hz == pytest.approx(fs, rel=1e-12)
    assert len(c.runs) == 3 and c.n_dropped == 0
    attrs = c.attrs()
    assert attrs["clock_gaps"] == 2 and attrs["clock_rate_hz"] == pytest.approx(fs)


def test_refuses_unusable_stamps():
    with pytest.raises(ClockError):
        fit_clock([1.0])
    with pytest.raises(ClockError, match="increasing"):
        fit_clock([0.0, 0.01, 0.01, 0.02])

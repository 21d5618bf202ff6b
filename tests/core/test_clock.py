"""The sample clock fitted to arrival stamps (calib.core.clock): rate, drops, gaps, jitter.

Stamps are made here from a model of the logger (true sample times, latency, stalls, lost samples, holes),
never with the code under test."""
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from calib.core.clock import LEVEL_WINDOW, MAX_DROP_RUN, ClockError, fit_clock


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
    """A 20 s pause and a lasting shift of 1.46 periods are gaps; a lasting shift of 0.46 periods (the logger's
    latency changing) is not: it is jitter, reported as the largest residual."""
    fs = 100.0
    t = np.concatenate([np.arange(1000) / fs, 30.0 + np.arange(1000) / fs,   # 20 s gap
                        40.0 + 0.0146 + np.arange(1000) / fs,                 # 1.46 periods off the grid
                        50.0 + 0.0192 + np.arange(1000) / fs])                # a further 0.46: latency
    c = fit_clock(t)
    assert [j for j, _ in c.gaps] == [999, 1999]
    assert c.gaps[0][1] == pytest.approx(20.01)
    assert len(c.runs) == 3 and c.n_dropped == 0
    assert c.max_residual_periods == pytest.approx(0.23, abs=0.01)   # +-0.23 about the line over the last run
    # the line through a step of 0.46 periods at the middle of 2000 samples tilts by 0.46 * 1.5 / 2000 = 3.5e-4
    assert c.rate_hz == pytest.approx(fs, rel=4e-4)
    attrs = c.attrs()
    assert attrs["clock_gaps"] == 2 and attrs["clock_rate_hz"] == c.rate_hz
    # the windows between the gaps, in seconds from the first stamp, split halfway
    w = c.windows()
    assert w[0] == (0.0, pytest.approx((9.99 + 30.0) / 2))
    assert w[1] == (pytest.approx((9.99 + 30.0) / 2), pytest.approx((39.99 + 40.0146) / 2))
    assert w[2][1] == pytest.approx(59.99 + 0.0192 + 0.005)


def ahrs_stamps(n, fs, seed, n_long=27):
    """Arrival stamps of an AHRS logger read over USB: a latency that grows by 0.024 periods a sample (steps
    of 1.024 periods) and falls back by 0.55 periods when it passes +0.3 periods (a step of 0.474 periods);
    ``n_long`` times a step 0.52 periods long that the next step pays back (steps of 1.52 then 0.5 periods).
    The latency stays within -0.25..+0.3 periods: no sample is lost."""
    rng = np.random.default_rng(seed)
    T = 1.0 / fs
    lat = np.empty(n)
    x = -0.25
    long_from = set(rng.choice(np.arange(10, n - 10), n_long, replace=False).tolist())
    pending = pay = False
    for i in range(n):
        pending |= i in long_from
        if pay:
            x -= 0.5
            pay = False
        elif pending and x <= -0.22:
            x += 0.52
            pending, pay = False, True
        else:
            x += 0.024
            if x > 0.3:
                x -= 0.55
        lat[i] = x
    return 3.0 + (np.arange(n) + lat) * T


def test_arrival_stamped_logger_is_jitter_not_gaps():
    """Steps of 10.24 ms, some of about 5 ms and a few of 15.2 ms, every stamp within +-0.3 periods of the line:
    one uniform 100 Hz clock, its jitter reported."""
    fs = 100.0
    t = ahrs_stamps(11_475, fs, 1)
    d = np.diff(t) * fs
    assert np.sum(d > 1.5) == 27 and np.sum(d < 0.6) >= 100 and np.median(d) == pytest.approx(1.024)
    c = fit_clock(t)
    assert c.uniform and not c.gaps and c.n_dropped == 0 and len(c.runs) == 1
    assert c.rate_hz == pytest.approx(fs, rel=1e-6)
    assert 0.25 < c.max_residual_periods <= 0.3
    assert 0.05 < c.jitter_std_periods < 0.2
    assert c.largest_step_s == pytest.approx(0.0152, abs=3e-4)
    assert "0 gap(s), 0 dropped sample(s)" in c.summary() and "100 Hz fitted" in c.summary()


def test_half_second_hole_is_a_gap_with_windows():
    fs = 100.0
    t = ahrs_stamps(3000, fs, 2, n_long=5)
    t[1500:] += 0.5   # half a second missing: 50 samples, more than MAX_DROP_RUN in a row
    c = fit_clock(t)
    assert [j for j, _ in c.gaps] == [1499]
    (a0, a1), (b0, b1) = c.windows()
    assert a0 == 0.0 and t[1499] - t[0] < a1 < t[1500] - t[0] and b0 == a1 and b1 > t[-1] - t[0]


@pytest.mark.parametrize("seed", range(3))
def test_dropped_samples_counted_under_arrival_jitter(seed):
    """Whole periods lost (runs of 1 to MAX_DROP_RUN samples) from the +-0.3 period arrival stamps: each run
    counted where it was lost, no gap."""
    rng = np.random.default_rng(10 + seed)
    fs = 200.0
    t = ahrs_stamps(12_000, fs, 20 + seed)
    keep = np.ones(len(t), dtype=bool)
    for s in rng.choice(np.arange(50, len(t) - 50, 400), 15, replace=False):
        keep[s:s + rng.integers(1, MAX_DROP_RUN + 1)] = False
    i = np.flatnonzero(keep)
    c = fit_clock(t[keep])
    assert not c.gaps
    np.testing.assert_array_equal(c.index - c.index[0], i - i[0])
    assert c.n_dropped == len(t) - keep.sum()
    assert c.rate_hz == pytest.approx(fs, rel=1e-6)


def logger(n, fs, rng, jitter, stalls, drops, gaps):
    """Stamps of a logger: sample i (before losses) made at T * i plus the hole lengths before it, stamped with a
    uniform latency of +-``jitter`` periods; ``stalls`` (start, length): those samples held until the next one
    is made and then sent in a burst; ``drops`` (start, length) lost; ``gaps`` (after sample, periods) holes.
    Returns the stamps and the positions (among the kept samples) after which the gaps lie."""
    T = 1.0 / fs
    clock_t = np.arange(n) * T
    for j, g in gaps:
        clock_t[j + 1:] += (g - 1.0) * T
    a = clock_t + jitter * T * rng.uniform(-1.0, 1.0, n)
    for s, length in stalls:
        a[s:s + length] = a[s + length]
    eps = 1e-3 * T   # a burst arrives in order, 1e-3 periods apart
    a = np.maximum.accumulate(a - eps * np.arange(n)) + eps * np.arange(n)
    keep = np.ones(n, dtype=bool)
    for s, length in drops:
        keep[s:s + length] = False
    kept = np.flatnonzero(keep)
    return a[keep], sorted(int(np.searchsorted(kept, j, side="right") - 1) for j, _ in gaps), kept


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), jitter=st.floats(0.0, 0.3), n_stalls=st.integers(0, 12),
       n_drops=st.integers(0, 12), n_gaps=st.integers(0, 2), whole_gap=st.booleans())
# a cluster of bursts and drops (samples 572-648) whose count flipped between two readings for every pass: the hole
# of 8.5 periods at sample 2996, far from it, was never marked
@example(seed=3835, jitter=0.0, n_stalls=11, n_drops=4, n_gaps=2, whole_gap=False)
def test_property_no_false_gap_every_gap_found(seed, jitter, n_stalls, n_drops, n_gaps, whole_gap):
    """Over random jitter (up to +-0.3 periods), bursts (up to MAX_DROP_RUN samples held and sent at once), lost
    samples (up to MAX_DROP_RUN in a row) and holes (a step of a whole number of periods above MAX_DROP_RUN + 1, or of
    2.35 periods or more that is not within 0.35 of a whole number: the stamps leave the line by 1.35 periods
    or more for good): exactly the holes are gaps, and every lost sample is counted."""
    rng = np.random.default_rng(seed)
    n, fs = 6000, 100.0
    sep = 3 * LEVEL_WINDOW   # holes apart from each other and from the ends by more than the level windows
    slots = rng.choice(np.arange(1, n // sep - 1), n_gaps, replace=False) if n_gaps else []
    gaps = []
    for sl in sorted(slots):
        g = float(rng.integers(MAX_DROP_RUN + 2, 200)) if whole_gap else \
            rng.integers(2, 30) + rng.uniform(0.35, 0.65)
        gaps.append((int(sl * sep + rng.integers(-50, 50)), g))
    # bursts and losses a level window away from a hole: nearer, a burst's return can pass for part of the hole
    near_gap = lambda s: any(abs(s - j) < LEVEL_WINDOW + 20 for j, _ in gaps)   # noqa: E731
    stalls = [(int(s), int(rng.integers(1, MAX_DROP_RUN + 1))) for s in rng.integers(30, n - 60, n_stalls)
              if not near_gap(s)]
    drops = []
    for s in np.sort(rng.integers(30, n - 60, n_drops)):   # runs apart: two that touch would be one longer run
        if not near_gap(s) and (not drops or s > sum(drops[-1]) + 1):
            drops.append((int(s), int(rng.integers(1, MAX_DROP_RUN + 1))))
    t, gap_at, kept = logger(n, fs, rng, jitter, stalls, drops, gaps)
    c = fit_clock(t)
    assert [j for j, _ in c.gaps] == gap_at
    # every lost sample counted: the clock index spans the true sample numbers of each run (where in a burst
    # a loss lies, the stamps cannot always tell)
    for a, b in c.runs:
        assert c.index[b - 1] - c.index[a] == kept[b - 1] - kept[a]


def test_refuses_unusable_stamps():
    with pytest.raises(ClockError):
        fit_clock([1.0])
    with pytest.raises(ClockError, match="increasing"):
        fit_clock([0.0, 0.01, 0.01, 0.02])

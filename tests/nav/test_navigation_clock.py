"""The navigator's time check uses the recording's fitted clock (calib.core.clock): stamps that jitter about
the line are not in the samples and navigate; a dropped sample would be integrated as one period, and is
refused naming the windows either side."""
from __future__ import annotations

import numpy as np
import pytest

from calib.io import recording
from calib.nav import navigation

FS = 100.0


def _recorded(tmp_path, name, t):
    n = len(t)
    rng = np.random.default_rng(3)
    acc = np.array([0.0, 0.0, 9.8]) / FS + 1e-5 * rng.standard_normal((n, 3))
    gyr = 1e-6 * rng.standard_normal((n, 3))
    ds = recording.make_dataset(acc, gyr, sample_rate_hz=FS, latitude_deg=45.0, accel_units="m s-1",
                                gyro_units="rad", accel_kind="increment", gyro_kind="increment", time=t)
    return recording.read_header(recording.write(ds, tmp_path / name))


def test_jittered_stamps_pass_and_a_dropped_sample_is_refused(tmp_path):
    n = 3000
    i = np.arange(n)
    jitter = 0.3 / FS * np.sin(0.7 * i)   # +-0.3 periods about the line, every step off the period
    navigation.check_time(_recorded(tmp_path, "jitter.nc", i / FS + jitter))
    t = np.delete(i, 1200) / FS            # sample 1200 lost: 1199 -> 1201 is two periods
    with pytest.raises(recording.RecordingError, match=r"1 dropped sample.*between samples 1199 and 1200") as exc:
        navigation.check_time(_recorded(tmp_path, "drop.nc", t))
    assert "start_s: 0, stop_s: 12; start_s: 12, stop_s: 30" in exc.value.fix   # halfway: 11.99 | 12.01 s

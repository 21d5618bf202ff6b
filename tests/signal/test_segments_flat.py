"""``segments._check_not_flat`` refuses exactly the records whose every column has a zero peak-to-peak span."""
import numpy as np
import pytest

from calib.signal import segments


def _cases():
    rng = np.random.default_rng(5)
    base = np.full((500, 3), 7.0)
    late = base.copy()
    late[400, 2] = 7.5  # differs only after the first 64 samples
    neg0 = base * 0.0
    neg0[::2] = -0.0
    inf = base.copy()
    inf[:, 1] = np.inf  # an infinite column has a NaN span: not flat
    nan = base.copy()
    nan[3, 0] = np.nan
    return [base, late, neg0, inf, nan, np.full((10, 3), -np.inf), rng.normal(size=(200, 3)),
            np.round(rng.normal(size=(300, 3)) * 0.2), base[:, :1]]


@pytest.mark.parametrize("y", _cases())
def test_flat_check_is_the_peak_to_peak_rule(y):
    with np.errstate(invalid="ignore"):
        flat = bool(np.all(np.ptp(y, axis=0) == 0))
    if flat:
        with pytest.raises(segments.SegmentError, match="flat"):
            segments._check_not_flat(y, "accel", "here")
    else:
        segments._check_not_flat(y, "accel", "here")

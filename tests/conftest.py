"""Fixtures shared by the test folders."""
from __future__ import annotations

import pytest

from calib.sim import simulator

#: the site of the short synthetic sessions of the diagnosis tests
SITE = {"latitude_deg": 30.58, "height_m": 0.0}


@pytest.fixture(scope="session")
def noise_record(tmp_path_factory):
    """A 2 h static record (counts) of the default simulated unit -- the long static record a user keeps beside a
    calibration session: the diagnosis measures the slow noise between its windows on it (Allan deviation)."""
    d = tmp_path_factory.mktemp("noise_record")
    path = d / "static_2h.nc"
    simulator.simulate_static_session({"mode": "counts", "duration_h": 2.0, "site": SITE, "sample_rate_hz": 100.0,
                                       "attitude_deg": {"pitch": 0.0, "roll": 0.0, "yaw": 0.0}},
                                      20261125, path, d / "static_2h.truth.json")
    return str(path)

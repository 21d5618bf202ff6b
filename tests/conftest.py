"""Fixtures shared by the test folders."""
from __future__ import annotations

import os

import pytest

from calib.sim.static_session import simulate_static_session

#: the test files that take longest (CPU s on one core, or wall s where they wait on subprocesses), longest
#: first. With several pytest-xdist workers (``python3 run.py test``: ``--dist loadfile``) the files are handed out
#: in this order, so that no long file starts last while the other cores run out of work. Order only: a file not
#: listed runs after these, in collection order; a stale list costs balance, never a test.
LONGEST_FIRST = [   # measured 2026-11-27 (pytest --junitxml, summed per file)
    "tests/diagnosis/test_diagnosis_proof.py",
    "tests/formats/test_noise.py",
    "tests/workflow/test_cluster.py",
    "tests/fieldcal/test_units_check.py",
    "tests/studies/test_sweeps.py",
    "tests/cli/test_exit_codes.py",
    "tests/diagnosis/test_real_proof.py",
    "tests/fieldcal/test_default_detection.py",
    "tests/diagnosis/test_unmodelled.py",
    "tests/sim/test_fisher.py",
    "tests/drift/test_lsq_sandwich.py",
    "tests/cli/test_mislabelled_shared.py",
    "tests/cli/test_refusals.py",
    "tests/studies/test_calibration_z.py",
    "tests/studies/test_workflow_support.py",
    "tests/fieldcal/test_offset_bound_modes.py",
]


def pytest_collection_modifyitems(config, items):
    """Under pytest-xdist: the files of :data:`LONGEST_FIRST` first, in its order (a stable sort: the tests of a
    file keep their order). A serial run keeps the collection order."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return
    rank = {f: i for i, f in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda it: rank.get(it.nodeid.split("::", 1)[0], len(rank)))


#: the site of the short synthetic sessions of the diagnosis tests
SITE = {"latitude_deg": 30.58, "height_m": 0.0}


@pytest.fixture(scope="session")
def noise_record(tmp_path_factory):
    """A 2 h static record (counts) of the default simulated unit -- the long static record a user keeps beside a
    calibration session: the diagnosis measures the slow noise between its windows on it (Allan deviation)."""
    d = tmp_path_factory.mktemp("noise_record")
    path = d / "static_2h.nc"
    simulate_static_session({"mode": "counts", "duration_h": 2.0, "site": SITE, "sample_rate_hz": 100.0,
                             "attitude_deg": {"pitch": 0.0, "roll": 0.0, "yaw": 0.0}},
                            20261125, path, d / "static_2h.truth.json")
    return str(path)

"""Units and rate checked by rotation before the gyro fit (calib.fieldcal.units_check), and the clock's rate in
the gyro integrals: synthetic sessions with burst arrival stamps and dropped samples, and the shared recordings."""
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import columns_settings, session, write_columns

from calib.core.errors import InputError
from calib.fieldcal import fieldcal_recording
from calib.fieldcal import units_check
from calib.fieldcal.units_check import UnitsCheckError, check_gyro_units
from calib.ingest import (
    ImportDataError,
    default_data_root,
    import_dataset,
    load_settings,
)
from calib.io import recording

REPO = Path(__file__).resolve().parents[2]
DATA = default_data_root()
needs_data = pytest.mark.skipif(not (DATA / "mikoff_mpu9150").is_dir(),
                                reason=f"shared recordings not found under {DATA} (set CALIB_DATA)")


def _clock_case(tmp_path, seed):
    s = session(seed, drop=0.01, burst=1.024)
    ds = import_dataset(columns_settings(write_columns(tmp_path, s)))
    return s, ds


def _check_clock_case(tmp_path, seed):
    s, ds = _clock_case(tmp_path, seed)
    fs = ds.attrs["sample_rate_hz"]
    assert abs(fs - s["fs"]) <= 3 * ds.attrs["clock_rate_std_hz"]
    assert ds.attrs["clock_dropped_samples"] == int(np.sum(np.diff(s["index"]) - 1))
    r = fieldcal_recording(ds, {"gravity_m_s2": s["gravity"]})
    assert r.units_check["status"] == "passed"
    np.testing.assert_allclose(r.gyro.scale_factors, s["gyro_scale_factors"], atol=1e-4)
    return s, ds


@pytest.mark.parametrize("seed", range(20))   # the acceptance: >= 20 seeds, in CI (about 25 s)
def test_clock_rate_and_gyro_scale_from_arrival_stamps(tmp_path, seed):
    _check_clock_case(tmp_path, seed)


def test_median_step_rate_is_the_counter_example(tmp_path):
    s, ds = _clock_case(tmp_path, 0)
    med = ds.attrs["clock_median_step_rate_hz"]
    assert med / s["fs"] == pytest.approx(1 / 1.024, rel=1e-3)
    ds_med = ds.copy()
    ds_med.attrs["sample_rate_hz"] = med  # the importer's former rate
    r = fieldcal_recording(ds_med, {"gravity_m_s2": s["gravity"]})
    err = r.gyro.scale_factors / s["gyro_scale_factors"] - 1.0
    np.testing.assert_allclose(err, 0.024, atol=2e-3)  # every integral 2.4 % too long


def _dataset(s, gyro, units, fs):
    return recording.make_dataset(s["accel"], gyro, sample_rate_hz=fs, latitude_deg=45.0, accel_units="m s-2",
                                  gyro_units=units, gravity_m_s2=s["gravity"], source="recorded")


@pytest.mark.parametrize("factor, units, field, words", [
    (1.0, "deg s-1", "gyro.units", "rad s-1 declared as deg s-1"),
    (180 / math.pi, "rad s-1", "gyro.units", "deg s-1 declared as rad s-1"),
])
def test_synthetic_units_mislabelled(factor, units, field, words):
    s = session(1)
    with pytest.raises(UnitsCheckError) as e:
        fieldcal_recording(_dataset(s, s["gyro"] * factor, units, s["fs"]), {"gravity_m_s2": s["gravity"]})
    assert e.value.field == field and words in str(e.value) and e.value.exit_code == 2
    assert isinstance(e.value, InputError)


@pytest.mark.parametrize("rate, words", [(200.0, "twice"), (50.0, "half")])
def test_synthetic_rate_mislabelled(tmp_path, rate, words):
    s = session(2)
    ds = import_dataset(columns_settings(write_columns(tmp_path, s, with_time=False), rate=rate, with_time=False))
    with pytest.raises(UnitsCheckError) as e:
        fieldcal_recording(ds, {"gravity_m_s2": s["gravity"]})
    assert e.value.field == "sample_rate_hz" and words in str(e.value)
    assert f"sample_rate_hz: {s['fs']:g}" in e.value.fix


def test_import_refuses_degrees_declared_as_radians(tmp_path):
    s = session(3)
    with pytest.raises(ImportDataError, match="gyro.units"):
        import_dataset(columns_settings(write_columns(tmp_path, s, gyro_factor=180 / math.pi)))


def test_force_and_disable():
    s = session(1)
    ds = _dataset(s, s["gyro"], "deg s-1", s["fs"])
    r = fieldcal_recording(ds, {"gravity_m_s2": s["gravity"]}, force=True)
    assert r.units_check["status"] == "forced" and r.units_check["scale"] == pytest.approx(180 / math.pi, rel=0.01)
    assert any("overridden by force" in n for n in r.notes)
    r = fieldcal_recording(ds, {"gravity_m_s2": s["gravity"], "units_check": False})
    assert r.units_check["status"] == "disabled"


def test_closure_per_pair_and_not_checked():
    s = session(4)
    iv = fieldcal_recording(_dataset(s, s["gyro"], "rad s-1", s["fs"]), {"gravity_m_s2": s["gravity"]}).intervals
    dt = np.full(len(s["gyro"]), 1 / s["fs"])
    uc = check_gyro_units(s["gyro"], s["accel"], iv, dt)
    assert uc.status == "passed" and abs(uc.scale - 1) < 0.02
    assert len(uc.closure_deg) == len(uc.pairs) >= 2 and np.all(uc.closure_best_deg < 5.0)  # 1 % scale, 0.5 % misalignment uncalibrated
    # turns about the vertical only: gravity never moves, nothing to check
    s = session(5, axes=[0, 0, 1])
    a, b = int(30 * s["fs"]), len(s["gyro"])
    iv = np.array([[100, a - 100], [b - 200, b - 10]])
    uc = check_gyro_units(s["gyro"], s["accel"], iv, dt[:b])
    assert uc.status == "not checked" and "at least 2" in uc.reason


def test_grid_of_factors_in_one_call_is_the_per_factor_closure_to_the_bit():
    """The grid search integrates every factor in one compiled call (factors in vector lanes); each cost must equal,
    bit for bit, the closure computed one factor at a time (the integration of ``w0 * s`` as numpy rounds it), over
    the whole grid and on arrival-stamp steps, so that the factor found (and every closure reported) is unchanged."""
    s = session(4, drop=0.01, burst=1.024)
    iv = fieldcal_recording(_dataset(s, s["gyro"], "rad s-1", s["fs"]), {"gravity_m_s2": s["gravity"]}).intervals
    dt = np.append(np.diff(s["time"]), 1 / s["fs"])   # uneven steps: bursts and dropped samples
    iv_, u, bias, gangle = units_check._pairs_problem(s["gyro"], s["accel"], iv, dt)
    angles = units_check._closure(s["gyro"], dt, iv_, u, bias, np.flatnonzero(gangle >= units_check.MIN_PAIR_ANGLE_DEG))
    grid = np.exp(np.linspace(math.log(units_check.SCALE_RANGE[0]), math.log(units_check.SCALE_RANGE[1]),
                              units_check.GRID_POINTS))
    one_by_one = np.array([float(np.sum(angles(x) ** 2)) for x in grid])
    assert np.array_equal(angles.grid_cost(grid), one_by_one)
    assert units_check.best_scale(angles) == units_check.best_scale(lambda x: angles(x))   # same search either way


# ----------------------------------------------------------------------------------- shared recordings


def _real(name):
    s = load_settings(REPO / "config" / "import" / f"{name}.yaml")
    fc = yaml.safe_load((REPO / "config" / "real" / f"{name}.yaml").read_text())["recording"].get("fieldcal") or {}
    return s, fc


@needs_data
@pytest.mark.parametrize("name", ["mikoff_imu0", "mikoff_imu1", "mikoff_imu2"])
def test_shared_mikoff_passes_and_mislabels_are_caught(name):
    s, fc = _real(name)
    r = fieldcal_recording(import_dataset(s), fc)
    assert r.units_check["status"] == "passed" and abs(r.units_check["scale"] - 1) < 0.05
    cases = [({"gyro": {**s["gyro"], "units": "deg s-1"}}, "gyro.units", "rad s-1 declared as deg s-1"),
             ({"sample_rate_hz": 200}, "sample_rate_hz", "twice"),
             ({"sample_rate_hz": 50}, "sample_rate_hz", "half")]
    for change, field, words in cases:
        with pytest.raises(UnitsCheckError) as e:
            fieldcal_recording(import_dataset({**s, **change}), fc)
        assert e.value.field == field and words in str(e.value), str(e.value)


@needs_data
def test_shared_imucal_passes_and_mislabels_are_caught():
    s, fc = _real("imucal_ferraris_A")
    ds = import_dataset(s)
    r = fieldcal_recording(ds, fc)
    assert r.method == "ferraris" and r.units_check["status"] == "passed"
    # the importer's turn check refuses these declarations already
    for change in ({"gyro": {**s["gyro"], "units": "rad s-1"}}, {"sample_rate_hz": 204.8}):
        with pytest.raises(ImportDataError):
            import_dataset({**s, **change})
    # and the rotation check refuses them on a recording that carries them
    cases = [("units", "rad s-1", "gyro.units", "deg s-1 declared as rad s-1"),
             ("rate", 204.8, "sample_rate_hz", "twice"), ("rate", 51.2, "sample_rate_hz", "half")]
    for what, value, field, words in cases:
        bad = ds.copy(deep=True)
        if what == "units":
            bad["gyro"].attrs["units"] = value
        else:
            bad.attrs["sample_rate_hz"] = value
        with pytest.raises(UnitsCheckError) as e:
            fieldcal_recording(bad, fc)
        assert e.value.field == field and words in str(e.value), str(e.value)

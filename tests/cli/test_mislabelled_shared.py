"""Every mislabelling of the shared real recordings is caught before any fit, with the likely mistake named.

Each shared import setting is altered the way users get it wrong (accelerometer g <-> m s-2, counts declared as
a physical unit, gyro rad s-1 <-> deg s-1, sample rate x2 and x1/2); the chain import -> validate -> fieldcal
must stop with exit 2 at the first stage that can see the mistake, naming the field. The one case no data
can reveal: the rate of a purely static record without time stamps (smac_adis16405: a rate reading does not
depend on the rate, and there is no rotation to integrate); it is refused for the lack of static poses instead.
"""
from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from calib import cli

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data"
pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason=f"shared real-data directory {DATA} missing")

SWAP = {"m s-2": "g", "g": "m s-2", "rad s-1": "deg s-1", "deg s-1": "rad s-1"}
# (recording, mistake, key path, new value or a function of the old one, stage that catches it, words named)
CASES = [
    ("imucal_ferraris_A", "accel g <-> m/s2", ("accel", "units"), SWAP, "import", ["accel.units", "m s-2"]),
    ("imucal_ferraris_A", "gyro rad <-> deg", ("gyro", "units"), SWAP, "import", ["gyro.units"]),
    ("imucal_ferraris_A", "rate x2", ("sample_rate_hz",), 2.0, "import", ["gyro.units", "sample_rate_hz"]),
    ("imucal_ferraris_A", "rate x1/2", ("sample_rate_hz",), 0.5, "import", ["gyro.units", "sample_rate_hz"]),
    ("imucal_ferraris_B", "accel counts as m/s2", ("accel", "units"), "m s-2", "import", ["accel.units"]),
    ("imucal_ferraris_B", "gyro counts as deg/s", ("gyro", "units"), "deg s-1", "import", ["gyro.units"]),
    ("imucal_ferraris_B", "rate x2", ("sample_rate_hz",), 2.0, "import", ["sample_rate_hz"]),
    ("imu_tk_xsens", "accel counts as m/s2", ("accel", "units"), "m s-2", "import", ["accel.units"]),
    ("imu_tk_xsens", "gyro counts as deg/s", ("gyro", "units"), "deg s-1", "import", ["gyro.units"]),
    ("imu_tk_xsens", "rate x2", ("sample_rate_hz",), 2.0, "import", ["sample_rate_hz", "least-squares clock"]),
    ("imu_tk_xsens", "rate x1/2", ("sample_rate_hz",), 0.5, "import", ["sample_rate_hz", "least-squares clock"]),
    ("smac_adis16405", "accel m/s2 <-> g", ("accel", "units"), SWAP, "import", ["accel.units", "'g'"]),
    ("smac_adis16405", "gyro deg <-> rad", ("gyro", "units"), SWAP, "validate", ["gyro", "degrees declared as ra"]),
] + [(f"mikoff_imu{k}", m, key, v, stage, words) for k in (0, 1, 2) for m, key, v, stage, words in (
    ("accel m/s2 <-> g", ("accel", "units"), SWAP, "import", ["accel.units", "m s-2"]),
    ("gyro rad <-> deg", ("gyro", "units"), SWAP, "fieldcal", ["gyro.units", "scaled by 57"]),
    ("rate x2", ("sample_rate_hz",), 2.0, "fieldcal", ["sample_rate_hz", "the true rate", "declare sample_rate_hz: 100"]),
    ("rate x1/2", ("sample_rate_hz",), 0.5, "fieldcal", ["sample_rate_hz", "half the true rate",
                                                          "declare sample_rate_hz: 100"]),
)]


@pytest.mark.parametrize("name, mistake, key, value, stage, words", CASES, ids=[f"{c[0]}: {c[1]}" for c in CASES])
def test_mislabelling_is_caught_before_the_fit(tmp_path, capsys, monkeypatch, name, mistake, key, value, stage,
                                               words):
    s = yaml.safe_load((ROOT / "config" / "import" / f"{name}.yaml").read_text())
    d = s
    for k in key[:-1]:
        d = d[k]
    old = d[key[-1]]
    d[key[-1]] = value[old] if isinstance(value, dict) else (old * value if isinstance(value, float) else value)
    settings = tmp_path / "settings.yaml"
    settings.write_text(yaml.safe_dump(s))
    monkeypatch.chdir(ROOT / "config" / "import")
    rec = tmp_path / "rec.nc"
    steps = [("import", ["import", str(settings), str(rec)]), ("validate", ["validate", str(rec)]),
             ("fieldcal", ["fieldcal", str(rec)])]
    for step, argv in steps:
        code = cli.main(["-q", *argv])
        err = capsys.readouterr().err
        if code != 0:
            break
    assert (step, code) == (stage, 2), err
    assert "Traceback" not in err
    for w in words:
        assert w in err, (w, err)
    if step == "import":
        assert not rec.exists()                                   # nothing written under the output name

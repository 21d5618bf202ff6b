"""matplotlib is loaded only when a figure is drawn: the modules that compute and also draw (the noise terms, the
static detection, the calibration study with its z-score seeds, the static navigation check, the diagnosis stage)
import their plotting module (calib.figures.*_plots) where they draw, so a step that draws nothing starts without
it."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("module", ["calib.signal.ieee952", "calib.signal.detect", "calib.studies.calibration",
                                    "calib.studies.navigation_stage", "calib.studies.diagnosis_stage"])
def test_import_loads_no_plotting(module):
    code = f"import sys, {module}\nprint(' '.join(sorted(sys.modules)))"
    mods = set(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True,
                              timeout=120).stdout.split())
    assert module in mods
    assert not {m for m in mods if m == "matplotlib" or m.startswith(("matplotlib.", "calib.figures"))}

"""The noise-seed study of the drift stage (calib.studies.drift.run_noise_seeds) leaves its products only: its
scratch folder of one seed's recording at a time is removed again, however the run ends."""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from calib.studies import drift as drift_study

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def cfg():
    return yaml.safe_load((ROOT / ".test" / "config.yaml").read_text())


def _run(cfg, out, **kw):
    dcfg = {**cfg["drift"], "window_h": 0.25}
    return drift_study.run_noise_seeds(out / "seeds.nc", out / "seeds.csv", out / "z.png", out / "m.json",
                                       cfg["navigation_session"], cfg["site"], dcfg, 2, 77, out / "scratch",
                                       log=lambda *a: None, **kw)


def test_no_scratch_folder_or_seed_file_is_left(tmp_path, cfg):
    _run(cfg, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.json", "seeds.csv", "seeds.nc", "z.png"]


def test_an_interrupted_run_leaves_no_seed_file(tmp_path, cfg, monkeypatch):
    from calib.drift import psobe

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(psobe, "load_window", interrupted)   # after the seed's recording is written
    with pytest.raises(KeyboardInterrupt):
        _run(cfg, tmp_path)
    assert list(tmp_path.iterdir()) == []

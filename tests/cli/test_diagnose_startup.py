"""What ``calib diagnose`` loads and reads: the command line starts without the plotting library and the importers
(matplotlib is loaded only when a figure is drawn), and each input file is checked sample by sample once -- with
the same report as when every load checks the file again."""
from __future__ import annotations

import contextlib
import json
import subprocess
import sys
from pathlib import Path

from calib import cli
from calib.io import recording, validation
from calib.sim.calibration_session import simulate_calibration_session

ROOT = Path(__file__).resolve().parents[2]
SHORT_SESSION = {"site": {"latitude_deg": 30.58, "height_m": 0.0}, "dwell_s": 20.0, "revolutions": 1}


def _modules_after(code: str) -> set:
    out = subprocess.run([sys.executable, "-c", code + "\nimport sys\nprint(' '.join(sorted(sys.modules)))"],
                         capture_output=True, text=True, cwd=ROOT, check=True, timeout=120).stdout
    return set(out.split())


def test_start_up_loads_no_plotting_and_no_importers():
    mods = _modules_after("import calib.cli, calib.diagnosis")
    assert "calib.diagnosis.run" in mods and "calib.signal.detect" in mods
    assert not {m for m in mods if m == "matplotlib" or m.startswith(("matplotlib.", "calib.ingest",
                                                                        "calib.figures"))}


def test_help_loads_no_numerical_library():
    """``calib --help`` (and every usage error) answers before numpy, the netCDF libraries, scipy, numba or
    matplotlib are loaded; the export formats it lists are calib.io.export_formats'."""
    mods = _modules_after("from calib import cli\ntry:\n    cli.main(['--help'])\nexcept SystemExit:\n    pass")
    assert not {m for m in mods if m.split(".")[0] in ("numpy", "xarray", "netCDF4", "scipy", "numba", "matplotlib")}
    from calib.io import EXPORT_FORMATS, export_formats

    assert export_formats.FORMATS == EXPORT_FORMATS


def test_a_figure_is_drawn_with_the_project_style(tmp_path):
    """calib.signal.detect loads no matplotlib on import; its figure (calib.figures.segment_plots) gets the
    project's rc settings (calib.figures.style) before anything is drawn, and the same file twice."""
    code = (
        "import sys, numpy as np\n"
        "from calib.signal import detect\n"
        "assert 'matplotlib' not in sys.modules and 'calib.figures.style' not in sys.modules\n"
        "rng = np.random.default_rng(0)\n"
        "acc = rng.normal(0, 1e-3, (3000, 3)); acc[1000:1500] += rng.normal(0, 1, (500, 3))\n"
        "gyr = rng.normal(0, 1e-3, (3000, 3)); gyr[1000:1500] += rng.normal(0, 1, (500, 3))\n"
        "det = detect.detect_static(acc, gyr, 100.0, init_s=5.0)\n"
        "made = []\n"
        "import matplotlib.figure as mf\n"
        "init = mf.Figure.__init__\n"
        "def spy(self, *a, **k):\n"
        "    import matplotlib\n"
        "    style = sys.modules.get('calib.figures.style')\n"
        "    made.append(style is not None and all(matplotlib.rcParams[k] == v for k, v in style.STYLE.items()))\n"
        "    init(self, *a, **k)\n"
        "mf.Figure.__init__ = spy\n"
        "from calib.figures import segment_plots\n"
        f"for name in ('a.svg', 'b.svg'):\n"
        f"    segment_plots.static_detection(acc, gyr, 100.0, det, r'{tmp_path}' + '/' + name)\n"
        "assert made == [True, True], made\n")
    mods = _modules_after(code)
    assert "calib.figures.style" in mods
    assert (tmp_path / "a.svg").read_bytes() == (tmp_path / "b.svg").read_bytes()


def test_each_input_is_read_once_with_the_same_report(tmp_path, capsys, monkeypatch, noise_record):
    rec = simulate_calibration_session(SHORT_SESSION, 8, tmp_path / "clean.nc")
    settings = tmp_path / "s.json"
    settings.write_text(json.dumps({"figures": False}))
    log = tmp_path / "reads.txt"
    body = validation._validate_body

    def counting(path, h, *rest):
        with open(log, "a") as fh:
            fh.write(f"{Path(path).resolve()}\n")
        return body(path, h, *rest)

    def reads():
        return log.read_text().split() if log.exists() else []

    monkeypatch.setattr(validation, "_validate_body", counting)
    argv = ["diagnose", str(rec), "--settings", str(settings), "--noise-record", noise_record]
    assert cli.main(argv + ["--out", str(tmp_path / "once")]) == 0
    assert sorted(reads()) == sorted(str(Path(p).resolve()) for p in (rec, noise_record))
    # every load checking the file again (as before): the same report, byte for byte
    monkeypatch.setattr(recording, "reuse_validation", contextlib.nullcontext)
    assert cli.main(argv + ["--out", str(tmp_path / "every")]) == 0
    assert len(reads()) > 2
    assert (tmp_path / "once" / "report.json").read_bytes() == (tmp_path / "every" / "report.json").read_bytes()
    assert (tmp_path / "once" / "report.md").read_bytes() == (tmp_path / "every" / "report.md").read_bytes()
    capsys.readouterr()


def test_a_recording_without_segment_table_is_checked_once(tmp_path, monkeypatch):
    """The diagnosis reads a recording as numpy arrays (recording.load_arrays), and one without a segment table again
    as a dataset for the static detection: its samples are checked by the first read only (outside the command's
    reuse_validation block too, as in the workflow's rules), and the detection gives it a table."""
    import xarray as xr

    from calib.diagnosis import load_for_diagnosis

    rec = simulate_calibration_session(SHORT_SESSION, 9, tmp_path / "with_table.nc")
    with xr.open_dataset(rec, engine="netcdf4") as ds:
        bare = ds.load().drop_vars([v for v in ds.variables if "segment" in ds[v].dims
                                    or v in ("segment_index", "table_angle")])
    path = recording.write(bare, tmp_path / "bare.nc")
    checked = []
    body = validation._validate_body
    monkeypatch.setattr(validation, "_validate_body", lambda p, h, *rest: (checked.append(p), body(p, h, *rest))[1])
    ds, refusal = load_for_diagnosis(path)
    assert refusal is None and "segment_index" in ds and "static detection" in ds.attrs["segments_from"]
    assert checked == [path]

"""Console discipline: standard output carries only the promised result, progress goes to standard error (a
live bar on a terminal, plain lines otherwise), ``--quiet`` silences it, warnings are one line each."""
from __future__ import annotations

import io
import subprocess
import sys
from pathlib import Path

import pytest

from calib import cli
from calib.core import progress
from calib.sim.calibration_session import simulate_calibration_session

ROOT = Path(__file__).resolve().parents[2]
SMALL_CONFIG = ROOT / ".test" / "config.yaml"


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    return simulate_calibration_session({"site": {"latitude_deg": 30.58, "height_m": 0.0},
                                         "dwell_s": 20.0, "revolutions": 1}, 8,
                                        tmp_path_factory.mktemp("cal") / "session.nc")


def test_calibrate_prints_only_its_result_on_stdout(tmp_path, capsys, session):
    out = tmp_path / "cal"
    code = cli.main(["calibrate", str(session), "--out", str(out), "--quick", "--config", str(SMALL_CONFIG)])
    cap = capsys.readouterr()
    assert code == 0
    assert cap.out == f"wrote {out}\n"                              # the promised output, nothing else
    assert "method x problem blocks" in cap.err                      # progress, on stderr
    assert "search bound" not in cap.err                              # exploratory runs do not cry wolf
    assert "Traceback" not in cap.err


def test_quiet_leaves_only_the_result(tmp_path, capsys, session):
    out = tmp_path / "cal"
    code = cli.main(["--quiet", "calibrate", str(session), "--out", str(out), "--quick", "--config",
                     str(SMALL_CONFIG)])
    cap = capsys.readouterr()
    assert code == 0 and cap.out == f"wrote {out}\n" and cap.err == ""
    progress.set_quiet(False)


def test_warnings_are_one_line_without_source():
    """A library warning during a command: one 'warning: ...' line, no file name, no source line."""
    code = ("import argparse, warnings\n"
            "from calib.cli import entry, shared\n"
            "def noisy(a):\n"
            "    warnings.warn('first line\\n   second line', UserWarning)\n"
            "    shared.emit('result')\n"
            "raise SystemExit(entry._dispatch(argparse.Namespace(cmd='demo', fn=noisy, quiet=False)))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout == "result\n"
    assert r.stderr == "warning: first line second line\n"


class _Tty(io.StringIO):
    def isatty(self):
        return True


def test_progress_is_a_bar_on_a_terminal_and_lines_in_a_log():
    tty, log = _Tty(), io.StringIO()
    for stream in (tty, log):
        bar = progress.Progress(4, "work", every_s=0.0, stream=stream)
        for k in range(1, 5):
            bar(k)
    assert "work: 100%" in tty.getvalue() and "4/4" in tty.getvalue()     # tqdm's bar
    lines = log.getvalue().splitlines()
    assert len(lines) == 4 and lines[-1].startswith("work 100.0% [")        # plain lines for a log file
    progress.set_quiet(True)
    quiet = io.StringIO()
    progress.Progress(2, "work", every_s=0.0, stream=quiet)(2)
    progress.set_quiet(False)
    assert quiet.getvalue() == ""

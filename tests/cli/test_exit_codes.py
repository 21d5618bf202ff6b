"""The exit-code contract of ``calib`` (calib.core.errors.EXIT_CODES): documented in ``calib --help`` and the
README, and kept by every outcome -- success 0, the diagnosis verdicts 0/1/3, usage and input errors 2, an
internal error 70 with its traceback in a log file, SIGINT 130 and SIGTERM 143 with no partial file left, a reader
gone from standard output 141."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from calib import cli
from calib.cli import recordings
from calib.core import errors
from calib.sim.calibration_session import simulate_calibration_session

ROOT = Path(__file__).resolve().parents[2]
SMALL_CONFIG = ROOT / ".test" / "config.yaml"
SHORT_SESSION = {"site": {"latitude_deg": 30.58, "height_m": 0.0}, "dwell_s": 20.0, "revolutions": 1}
CONTRACT = {0, 1, 2, 3, 70, 130, 141, 143}


def calib(*argv, **kw):
    """``calib ARGV`` in a fresh interpreter (what a user's terminal shows)."""
    return subprocess.run([sys.executable, "-m", "calib.cli", *map(str, argv)], capture_output=True, text=True,
                          cwd=kw.pop("cwd", ROOT), timeout=kw.pop("timeout", 120), **kw)


def test_contract_is_documented_in_help_and_readme(capsys):
    assert {code for code, _ in errors.EXIT_CODES} == CONTRACT
    assert (errors.EXIT_SIGINT, errors.EXIT_SIGTERM) == (128 + signal.SIGINT, 128 + signal.SIGTERM)
    with pytest.raises(SystemExit) as ei:
        cli.main(["--help"])
    assert ei.value.code == 0
    help_text = capsys.readouterr().out
    epilog = help_text[help_text.index("exit codes:"):]
    assert {int(m) for m in re.findall(r"^\s+(\d+)\s", epilog, re.M)} == CONTRACT
    readme = (ROOT / "README.md").read_text()
    section = readme[readme.index("## Exit codes"):]
    section = section[:section.index("\n## ")]
    rows = re.findall(r"^\| ([\d /]+) \|", section, re.M)
    assert {int(c) for r in rows for c in r.split("/")} == CONTRACT


def test_argparse_usage_errors_stay_2(capsys):
    for argv in (["navigate"], ["simulate", "nonsense", "x.nc"], ["validate", "a.nc", "--hours", "1"], []):
        with pytest.raises(SystemExit) as ei:
            cli.main(argv)
        assert ei.value.code == 2
    assert "usage: calib" in capsys.readouterr().err


def test_success_is_0(tmp_path, capsys):
    out = tmp_path / "nav.nc"
    assert cli.main(["simulate", "navigation", str(out), "--config", str(SMALL_CONFIG), "--hours", "0.005"]) == 0
    assert cli.main(["validate", str(out)]) == 0
    assert cli.main(["navigate", str(out), "--out", str(tmp_path / "errors.nc")]) == 0
    assert "plausible: static accel norm" in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["errors.nc", "nav.nc", "nav.truth.json"]


def test_diagnose_verdicts_map_to_0_and_3(tmp_path, capsys, noise_record):
    settings = tmp_path / "s.json"
    settings.write_text(json.dumps({"figures": False}))
    clean = simulate_calibration_session(SHORT_SESSION, 8, tmp_path / "clean.nc")
    assert cli.main(["diagnose", str(clean), "--out", str(tmp_path / "d0"), "--settings", str(settings),
                     "--noise-record", noise_record]) == 0
    few = simulate_calibration_session({**SHORT_SESSION, "positions_per_phase": 1, "step_deg": 90.0}, 1,
                                       tmp_path / "few.nc")
    assert cli.main(["diagnose", str(few), "--out", str(tmp_path / "d3"), "--settings", str(settings)]) == 3
    verdicts = [json.loads((tmp_path / d / "report.json").read_text())["verdict"] for d in ("d0", "d3")]
    assert verdicts == ["adequate", "inconclusive"]


def test_internal_error_is_one_line_and_a_log_file(tmp_path, capsys, monkeypatch):
    from calib.studies import stages

    def bug(*a, **k):
        raise ZeroDivisionError("division by zero inside a stage")

    monkeypatch.setattr(stages, "simulate_navigation", bug)
    code = cli.main(["simulate", "navigation", str(tmp_path / "x.nc"), "--config", str(SMALL_CONFIG),
                     "--hours", "0.005"])
    err = capsys.readouterr().err
    assert code == 70
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "calib simulate: internal error: ZeroDivisionError: division by zero inside a stage" in err
    log = Path(re.search(r"traceback in (\S+?);", err).group(1))
    try:
        text = log.read_text()
        assert "Traceback (most recent call last)" in text and "in bug" in text
    finally:
        log.unlink()
    assert list(tmp_path.iterdir()) == []


def test_user_errors_print_no_traceback_on_the_terminal(tmp_path):
    """In a fresh interpreter: a folder given as a recording, --nav-rate 0, a missing config."""
    r = calib("validate", tmp_path)
    assert r.returncode == 2 and "is a folder" in r.stderr and "Traceback" not in r.stderr
    r = calib("navigate", tmp_path / "x.nc", "--out", tmp_path / "o.nc", "--nav-rate", "0")
    assert r.returncode == 2 and "--nav-rate must be positive" in r.stderr and "Traceback" not in r.stderr
    r = calib("simulate", "calibration", tmp_path / "x.nc", "--config", tmp_path / "missing.yaml")
    assert r.returncode == 2 and "config file not found" in r.stderr and "Traceback" not in r.stderr
    assert list(tmp_path.iterdir()) == []
    # the default config is the source tree's, whatever the working directory
    r = calib("simulate", "calibration", tmp_path / "y.nc", cwd=tmp_path)
    assert r.returncode == 0 and r.stdout.startswith(f"wrote {tmp_path / 'y.nc'}"), r.stderr


@pytest.mark.parametrize("signum, code, name", [(signal.SIGINT, 130, "SIGINT"), (signal.SIGTERM, 143, "SIGTERM")])
def test_signals_leave_no_partial_file_and_keep_the_earlier_output(tmp_path, signum, code, name):
    """A long simulation killed while it writes: the temporary file goes, the earlier output stays."""
    out = tmp_path / "nav.nc"
    out.write_bytes(b"earlier good output")
    proc = subprocess.Popen([sys.executable, "-m", "calib.cli", "simulate", "navigation", str(out), "--config",
                             str(SMALL_CONFIG), "--hours", "200"], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            # a run started in the background inherits SIGINT ignored (shell job control); the
                            # user's terminal does not: give the child the default disposition a terminal gives
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 60
        while not any(p.name.endswith(".part") for p in tmp_path.iterdir()):
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.05)
        time.sleep(0.3)
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == code, err
    assert f"interrupted by {name}" in err and "Traceback" not in err
    assert out.read_bytes() == b"earlier good output"
    assert sorted(os.listdir(tmp_path)) == ["nav.nc"]


def _main_as_from_a_terminal(signum, argv) -> int:
    """``cli.main(argv)`` with ``signum`` disposed as a terminal gives it: a run started in the background (nohup, a
    CI runner) inherits SIGINT ignored, and calib leaves an ignored signal alone."""
    old = signal.signal(signum, signal.default_int_handler if signum == signal.SIGINT else signal.SIG_DFL)
    try:
        return cli.main(argv)
    finally:
        signal.signal(signum, old)


@pytest.mark.parametrize("signum, code, name", [(signal.SIGINT, 130, "SIGINT"), (signal.SIGTERM, 143, "SIGTERM")])
def test_what_an_interrupted_library_raises_is_the_interruption(monkeypatch, capsys, signum, code, name, tmp_path):
    """A signal that lands inside an extension module while it loads comes back as that module's ImportError
    ("initialization failed"): still the interruption's exit code and line, not an internal error."""
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))   # the internal error's log below: not in /tmp
    def interrupted_import(a):
        try:
            os.kill(os.getpid(), signum)
            time.sleep(5)
        except KeyboardInterrupt:
            raise ImportError("initialization failed") from None

    monkeypatch.setattr(recordings, "cmd_validate", interrupted_import)
    assert _main_as_from_a_terminal(signum, ["validate", "x.nc"]) == code
    err = capsys.readouterr().err
    assert f"calib validate: interrupted by {name}" in err and "internal error" not in err
    monkeypatch.setattr(recordings, "cmd_validate", lambda a: (_ for _ in ()).throw(ImportError("a bug")))
    assert cli.main(["validate", "x.nc"]) == 70   # no signal: an ImportError is a bug
    capsys.readouterr()
    logs = list(tmp_path.glob("calib-error-*.log"))
    assert len(logs) == 1 and "ImportError: a bug" in logs[0].read_text()


@pytest.mark.parametrize("signum, code, name", [(signal.SIGINT, 130, "SIGINT"), (signal.SIGTERM, 143, "SIGTERM")])
def test_a_signal_landing_in_a_destructor_still_interrupts(monkeypatch, capsys, signum, code, name):
    """A signal whose interruption is raised inside a ``__del__`` (llvmlite frees its objects so while numba loads
    its cache: seen as "Exception ignored ... Traceback" on the terminal and the command running on to its end) is
    not lost: the command stops with the interruption's code and line, nothing of a traceback printed, and the work
    after it never runs."""
    reached = []

    class Freed:
        def __del__(self):
            os.kill(os.getpid(), signum)
            time.sleep(0.05)   # the handler runs in here: its exception cannot leave a destructor

    def work(a):
        Freed()
        for _ in range(300):   # 3 s of work after the signal; an interruption raised again lands in here
            time.sleep(0.01)
        reached.append("the end")
        return 0

    monkeypatch.setattr(recordings, "cmd_validate", work)
    assert _main_as_from_a_terminal(signum, ["validate", "x.nc"]) == code
    err = capsys.readouterr().err
    assert f"calib validate: interrupted by {name}" in err, err
    assert "Traceback" not in err and "Exception ignored" not in err, err
    assert reached == []


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_after_the_outcome_changes_nothing(tmp_path, signum):
    """The command's process, once its outcome is decided (here: a refusal, exit 2), ignores SIGINT / SIGTERM until
    it has ended: Python resets its handlers while it shuts down, and a Ctrl-C then killed the process silently
    (exit -2, no line said) after the result was complete."""
    code = ("import os, signal, sys, time\n"
            "from calib import cli\n"
            f"rc = cli.main(['validate', r'{tmp_path / 'missing.nc'}'], exiting=True)\n"
            f"os.kill(os.getpid(), {int(signum)})\n"
            "time.sleep(0.2)\n"
            "print('still here', rc, flush=True)\n"
            "sys.exit(rc)\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "still here 2" in r.stdout, (r.returncode, r.stdout, r.stderr)
    assert "Traceback" not in r.stderr


def test_version_prints_the_package_version_and_exits_0():
    from calib import __version__

    r = subprocess.run([sys.executable, "-m", "calib.cli", "--version"], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.strip() == f"calib {__version__}" and r.stderr == ""


_ENDING = """
import atexit, sys, threading, weakref
from calib import cli

class Module:   # stands for a library's objects
    pass

KEEP = Module()
weakref.finalize(KEEP, print, "finalizer at exit ran")   # atexit=True: run by the exit handlers
atexit.register(print, "exit handler ran")
if sys.argv[1] == "thread":   # a non-daemon thread still running: Python's own exit waits for it
    threading.Thread(target=lambda: (__import__("time").sleep(0.3), print("thread finished", flush=True))).start()
sys.stdout.write("x" * 200000)   # buffered output, delivered whole
sys.argv = ["calib", "validate", sys.argv[2]]
cli.run()
"""


def test_the_command_ends_as_python_ends(tmp_path):
    """``calib`` ends through the interpreter's normal exit (calib.cli.run): the exit code of the command, its exit
    handlers and finalizers run, its buffered output flushed whole; with a non-daemon thread still running it exits
    after that thread."""
    missing = tmp_path / "missing.nc"
    r = subprocess.run([sys.executable, "-c", _ENDING, "plain", str(missing)], capture_output=True, text=True,
                       cwd=ROOT, timeout=120)
    assert r.returncode == errors.EXIT_INPUT, r.stderr
    assert "missing.nc" in r.stderr and "Traceback" not in r.stderr
    assert r.stdout.startswith("x" * 200000)
    assert "exit handler ran" in r.stdout and "finalizer at exit ran" in r.stdout
    r = subprocess.run([sys.executable, "-c", _ENDING, "thread", str(missing)], capture_output=True, text=True,
                       cwd=ROOT, timeout=120)
    assert r.returncode == errors.EXIT_INPUT, r.stderr
    assert "thread finished" in r.stdout + r.stderr and "exit handler ran" in r.stdout


def test_a_reader_gone_from_standard_output_is_141_not_an_input_error(tmp_path):
    """``calib ... | head -1`` whose reader left before the promised line: the command stops silently with 141 (as a
    shell reports a command its pipe's reader left), not 2 with "error: Broken pipe", which blamed the input."""
    out = tmp_path / "nav.nc"
    assert cli.main(["simulate", "navigation", str(out), "--config", str(SMALL_CONFIG), "--hours", "0.005"]) == 0
    r, w = os.pipe()
    os.close(r)   # nobody reads: the first write to standard output fails with EPIPE
    try:
        p = subprocess.run([sys.executable, "-m", "calib.cli", "validate", str(out)], stdout=w, stderr=subprocess.PIPE,
                           text=True, cwd=ROOT, timeout=120)
    finally:
        os.close(w)
    assert p.returncode == errors.EXIT_SIGPIPE == 141, p.stderr
    assert "error" not in p.stderr and "Traceback" not in p.stderr and "Exception ignored" not in p.stderr, p.stderr

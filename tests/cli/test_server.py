"""The warm server of ``calib diagnose`` (calib.cli.server): a served run is the cold run -- the same files byte for
byte, the same lines, the same exit codes and refusals --, a signal of the command reaches its run, a command
killed outright leaves no run behind, a command of other code is never served, and the server ends when idle.

Every test here uses its own socket folder (``XDG_RUNTIME_DIR`` in a temporary folder) and stops its servers; the
rest of the tests run with ``CALIB_SERVER=off`` (tests/conftest.py)."""
from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from calib.cli import server
from calib.sim import simulator

ROOT = Path(__file__).resolve().parents[2]
SHORT_SESSION = {"site": {"latitude_deg": 30.58, "height_m": 0.0}, "dwell_s": 20.0, "revolutions": 1}
#: a client that says whether a server ran the command: the marker is its last line on standard error
CLIENT = ("import sys\nfrom calib.cli import server\ncode = server.run_served(sys.argv[1:])\n"
          "print('SERVED' if code is not None else 'NOT SERVED', file=sys.stderr)\n"
          "sys.exit(0 if code is None else code)\n")
pytestmark = pytest.mark.skipif(not (hasattr(os, "fork") and hasattr(socket, "send_fds")),
                                reason="no fork / AF_UNIX descriptor passing on this platform")


def _env(runtime, **extra):
    # a server the tests fail to stop ends itself two minutes after its last command
    env = {**os.environ, server.ENV: "on", "XDG_RUNTIME_DIR": str(runtime), server.IDLE_ENV: "120", **extra}
    env.pop("PYTEST_CURRENT_TEST", None)
    return env


def _sock(runtime):
    d = Path(runtime) / f"calib-{os.getuid()}"
    return sorted(d.glob("srv-*.sock")) if d.is_dir() else []


def _stop(env):
    subprocess.run([sys.executable, "-m", "calib.cli", "server", "stop"], env=env, capture_output=True, timeout=60)


@pytest.fixture
def short_tmp():
    """A folder with a short path (a socket's path has at most 107 bytes; a longer runtime folder is not used)."""
    d = Path(tempfile.mkdtemp(prefix="cs"))
    yield d
    shutil.rmtree(d, ignore_errors=True)


@pytest.fixture(scope="module")
def warm(tmp_path_factory):
    """A recording, the result of a cold ``calib diagnose`` of it (which starts the server), and the server, warm."""
    d = tmp_path_factory.mktemp("served")
    runtime = Path(tempfile.mkdtemp(prefix="cs"))   # short: see short_tmp
    rec = simulator.simulate_calibration_session(SHORT_SESSION, 8, d / "rec.nc")
    env = _env(runtime)
    cold = subprocess.run([sys.executable, "-m", "calib.cli", "diagnose", str(rec), "--out", str(d / "out")],
                          env=env, capture_output=True, text=True, timeout=300)
    files = {p.name: p.read_bytes() for p in sorted((d / "out").iterdir())}
    t0 = time.monotonic()
    while not _sock(runtime) and time.monotonic() - t0 < 120:
        time.sleep(0.2)
    assert _sock(runtime), "the cold run started no server"
    yield {"dir": d, "rec": rec, "env": env, "cold": cold, "files": files, "runtime": runtime}
    _stop(env)
    shutil.rmtree(runtime, ignore_errors=True)


def _served(warm, *argv, **kw):
    return subprocess.run([sys.executable, "-c", CLIENT, *argv], env=warm["env"], capture_output=True, text=True,
                          timeout=300, cwd=kw.get("cwd", ROOT))


def test_a_served_run_is_the_cold_run(warm):
    d, cold = warm["dir"], warm["cold"]
    assert cold.returncode in (0, 1, 3), cold.stderr
    assert len(warm["files"]) == 4   # report.json, report.md and the two figures
    for p in (d / "out").iterdir():
        p.unlink()
    got = _served(warm, "diagnose", str(warm["rec"]), "--out", str(d / "out"))
    assert got.stderr.splitlines()[-1] == "SERVED", got.stderr
    assert got.returncode == cold.returncode
    assert got.stdout == cold.stdout
    assert got.stderr.rsplit("SERVED", 1)[0] == cold.stderr
    assert {p.name: p.read_bytes() for p in sorted((d / "out").iterdir())} == warm["files"]


def test_relative_paths_are_the_command_s_folder(warm, tmp_path):
    """The run works in the command's folder with the command's environment: a relative --out lands there."""
    got = _served(warm, "diagnose", str(warm["rec"]), "--out", "rel", cwd=tmp_path)
    assert got.stderr.splitlines()[-1] == "SERVED", got.stderr
    _assert_outputs_of_the_cold_run(warm, tmp_path / "rel", "rel")


def _assert_outputs_of_the_cold_run(warm, out, named):
    """The files of the cold run in ``out``, byte for byte; report.json names its figures by the --out given."""
    got = {p.name: p.read_bytes() for p in sorted(Path(out).iterdir())}
    assert got.keys() == warm["files"].keys()
    assert all(got[n] == warm["files"][n] for n in got if n != "report.json")
    figures = json.loads(got["report.json"])["figures"]
    assert figures == [f"{named}/residuals_before_after.png", f"{named}/allan_deviation.png"]
    cold = warm["files"]["report.json"].replace(str(warm["dir"] / "out").encode(), named.encode())
    assert got["report.json"] == cold


def test_a_refusal_is_the_same_when_served(warm, tmp_path):
    bad = tmp_path / "bad.nc"
    bad.write_text("not a netCDF file\n")
    argv = ["diagnose", str(bad), "--out", str(tmp_path / "o")]
    cold = subprocess.run([sys.executable, "-m", "calib.cli", *argv], env={**warm["env"], server.ENV: "off"},
                          capture_output=True, text=True, timeout=120)
    got = _served(warm, *argv)
    assert got.stderr.splitlines()[-1] == "SERVED", got.stderr
    assert cold.returncode == got.returncode == 2
    assert got.stderr.rsplit("SERVED", 1)[0] == cold.stderr and "bad.nc" in cold.stderr
    usage = _served(warm, "diagnose", str(bad))   # argparse's usage error (no --out): its exit code 2, its text
    assert usage.returncode == 2 and "--out" in usage.stderr


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs /proc to find the run's process")
@pytest.mark.parametrize("signum, code, name", [(signal.SIGINT, 130, "SIGINT"), (signal.SIGTERM, 143, "SIGTERM")])
def test_a_signal_of_the_command_ends_its_run(warm, tmp_path, signum, code, name):
    """The signal comes once the run has its handlers, ~1 s before its end. On a loaded machine it may come later,
    even after the run: then the run's outputs are the whole set (never a part of it) and the test tries again, up
    to three times, until one run was ended by it (exit 130 / 143, its line, nothing written)."""
    outcomes = []
    for attempt in range(3):
        out = tmp_path / f"o{attempt}"
        p = subprocess.Popen([sys.executable, "-c", CLIENT, "diagnose", str(warm["rec"]), "--out", str(out)],
                             env=warm["env"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))   # as from a terminal
        _under_way(warm["runtime"], p.pid)
        p.send_signal(signum)
        _, err = p.communicate(timeout=120)
        written = sorted(x.name for x in out.iterdir()) if out.exists() else []
        if written:   # the signal came after the outputs were complete: all of them, as the cold run wrote them
            _assert_outputs_of_the_cold_run(warm, out, str(out))
            assert p.returncode in (code, warm["cold"].returncode), err
        else:
            assert p.returncode == code, err
            assert f"calib diagnose: interrupted by {name}" in err
        outcomes.append((p.returncode, written))
        if p.returncode == code and not written:
            break
    assert outcomes[-1] == (code, []), outcomes


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs /proc to find the run's process")
def test_a_signal_the_command_ignores_is_ignored_by_its_run(warm, tmp_path):
    """A command started with SIGINT ignored (in the background of a shell, under nohup, by a CI runner) goes on
    through a Ctrl-C as a cold one does: its run inherits the disposition."""
    out = tmp_path / "o"
    p = subprocess.Popen([sys.executable, "-c", CLIENT, "diagnose", str(warm["rec"]), "--out", str(out)],
                         env=warm["env"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    _under_way(warm["runtime"], p.pid)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert p.returncode == warm["cold"].returncode, err
    _assert_outputs_of_the_cold_run(warm, out, str(out))


def _under_way(runtime, client: int):
    """Wait until the run is under way and a signal of the command reaches it: the server has forked the run, the
    run has started its command (its helper process is there: forked by ``calib diagnose`` inside the command's
    signal handling) and the command ``client`` passes signals on (it catches SIGTERM from then on:
    /proc/PID/status SigCgt). Before that a signal ends a run that has not started -- another outcome. A served
    run of this recording takes over 1 s from there."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < 60:
        if _catches(client, signal.SIGTERM) and any(_children(pid) for pid in _runs(runtime)):
            return
        time.sleep(0.01)
    raise AssertionError("no run of the server started its command")


def _catches(pid, signum) -> bool:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("SigCgt:"):
                return bool(int(line.split()[1], 16) >> (signum - 1) & 1)
    except (OSError, ValueError):
        pass
    return False


def _children(pid) -> list:
    try:
        return Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return []


def _runs(runtime):
    """Processes forked from the test's servers that are still alive (the server itself excluded)."""
    return [int(x) for _, pid, _ in _servers(runtime) for x in _children(pid)]


def _servers(runtime):
    env = {server.ENV: "on", "XDG_RUNTIME_DIR": str(runtime)}
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        return server.servers()
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs /proc to find the run's process")
def test_a_command_killed_outright_leaves_no_run(warm, tmp_path):
    """As the signal test: a kill that came after the run's end finds the whole set written; then again, up to
    three times, until one run was ended by it with nothing written."""
    for attempt in range(3):
        out = tmp_path / f"o{attempt}"
        p = subprocess.Popen([sys.executable, "-c", CLIENT, "diagnose", str(warm["rec"]), "--out", str(out)],
                             env=warm["env"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        _under_way(warm["runtime"], p.pid)
        p.kill()
        p.wait(timeout=30)
        t0 = time.monotonic()
        while _runs(warm["runtime"]) and time.monotonic() - t0 < 30:
            time.sleep(0.1)
        assert _runs(warm["runtime"]) == []
        if not out.exists() or list(out.iterdir()) == []:
            break
        _assert_outputs_of_the_cold_run(warm, out, str(out))   # the run had ended: all of its outputs
    else:
        pytest.fail("the run ended before the kill in all three attempts")


def test_a_command_of_other_code_is_not_served(warm, tmp_path):
    """A setting read while the libraries load (here NUMBA_OPT) is part of the key: that command runs cold."""
    got = subprocess.run([sys.executable, "-c", CLIENT, "diagnose", str(warm["rec"]), "--out", str(tmp_path / "o")],
                         env={**warm["env"], "NUMBA_OPT": "2"}, capture_output=True, text=True, timeout=120)
    assert got.stderr.splitlines()[-1] == "NOT SERVED" and got.returncode == 0
    assert not (tmp_path / "o").exists()


def test_the_key_follows_the_package_files(tmp_path, monkeypatch):
    import calib

    pkg = tmp_path / "calib"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "m.py").write_text("x = 1\n")
    monkeypatch.setattr(calib, "__file__", str(pkg / "__init__.py"))
    k0 = server.key()
    assert server.key() == k0
    (pkg / "m.py").write_text("x = 2\n")   # same size, a new modification time
    os.utime(pkg / "m.py", ns=(time.time_ns(), time.time_ns() + 10**9))
    assert server.key() != k0
    monkeypatch.setenv("CALIB_SOMETHING", "1")
    k1 = server.key()
    monkeypatch.setenv("CALIB_SERVER_IDLE", "5")   # the server's own settings are not the code's
    assert server.key() == k1


def test_a_folder_others_may_enter_is_not_used(short_tmp, monkeypatch):
    tmp_path = short_tmp
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    assert server.folder() == tmp_path / f"calib-{os.getuid()}"
    (tmp_path / f"calib-{os.getuid()}").chmod(0o755)
    assert server.folder() is None
    monkeypatch.setenv(server.ENV, "on")
    assert server.run_served(["diagnose", "x.nc", "--out", "o"]) is None


def test_an_idle_server_ends_and_removes_its_files(short_tmp):
    tmp_path = short_tmp
    env = _env(tmp_path, CALIB_SERVER_IDLE="0.5")
    code = "from calib.cli import server\nserver.warm = lambda: None\nraise SystemExit(server.serve(server.key()))\n"
    p = subprocess.Popen([sys.executable, "-c", code], env=env)
    t0 = time.monotonic()
    while not _sock(tmp_path) and p.poll() is None and time.monotonic() - t0 < 60:
        time.sleep(0.05)
    assert _sock(tmp_path), "the server never listened"
    assert p.wait(timeout=30) == 0
    assert _sock(tmp_path) == []
    assert list((tmp_path / f"calib-{os.getuid()}").glob("srv-*.lock")) == []   # nothing left behind


def test_only_diagnose_is_served():
    assert server.served(["diagnose", "r.nc", "--out", "o"]) and server.served(["-q", "diagnose", "r.nc"])
    assert not server.served(["validate", "r.nc"]) and not server.served(["diagnose", "--help"])
    assert not server.served([])

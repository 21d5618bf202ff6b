"""A resident process that keeps ``calib diagnose``'s libraries loaded: the command's second and later runs start
warm.

A cold ``calib diagnose FILE`` spends about half its wall time before it reads a byte of FILE: importing numpy,
scipy and numba (~0.9 s), initialising numba and loading its cached kernels (~0.3 s), and, in its helper,
importing matplotlib and loading fonts (~0.8 s). None of that depends on the file. After a cold run the command
starts a server in the background (one per user and *key*, below) that does all of it once and then waits on a
UNIX socket; the next ``calib diagnose`` connects, hands over its arguments, working directory, environment, umask,
signal dispositions and its standard input, output and error (the file descriptors themselves), and the server
forks a fresh copy of its warmed state to run exactly the code a cold command runs (:func:`calib.cli.main`). The
copy writes the command's output files itself (atomically, as always) and its lines to the command's own
terminal; the command waits for the exit code and exits with it. What is not shared between runs: everything --
each run is a new process forked from the same warmed state, which no run changes.

Trust:

* **Same code**: the key hashes the interpreter, ``sys.path`` (but for its first entry, the launcher's folder) and
  the modification stamps of its folders (a package installed or removed), every file of the calib package (size
  and modification time), the interpreter's flags and warning options, and the environment variables read at
  import time (``CALIB_*``, ``NUMBA_*``, ``MPL*``, ``PYTHON*``, ``LD_*``, thread counts, locale, ``HOME``,
  ``XDG_*``, ``TMPDIR``). A command whose key differs never reaches a server started from other code; a server
  whose files changed under it stops at the next request or within 30 s. What the run looks up at run time (the
  temporary folder, every setting calib reads) comes from the command's own environment.
* **Same result**: the served run is the cold run's code on the cold run's inputs; tests/cli/test_server.py compares
  the files, the lines and the exit codes of a served run with those of a cold run byte for byte.
* **Same refusals and signals**: a Ctrl-C or SIGTERM of the command is passed to the run (which ends as a cold run
  ends: exit 130 / 143, no partial file); a command killed outright (SIGKILL, terminal closed) leaves its run a
  SIGTERM. A run that ends without an exit code (killed) makes the command say so in one line, exit 70.
* **Only the user**: the socket lives in a folder only the user can enter (``$XDG_RUNTIME_DIR/calib-UID`` or
  ``/tmp/calib-UID``, mode 0700, refused if anyone else owns it or may enter it), and the server checks the
  connecting process's user id.
* **Nothing lingering**: the server ends after ``CALIB_SERVER_IDLE`` seconds without a request (default 600);
  ``calib server stop`` ends it now; ``CALIB_SERVER=off`` turns the whole mechanism off (the tests and CI run with
  it off, except the tests of this module).

Served: ``calib diagnose`` only (the command with a latency target). What a served run cannot mimic: resource
limits (``ulimit``) set in the command's shell after the server started -- the run has the server's; a stopped
command (Ctrl-Z) does not stop its run.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import signal
import socket
import stat
import struct
import sys
import tempfile
import time
from pathlib import Path

from calib import cli   # the package this module belongs to (loaded before it)
from calib.core.errors import EXIT_INTERNAL, EXIT_SIGINT

ENV = "CALIB_SERVER"
IDLE_ENV = "CALIB_SERVER_IDLE"
IDLE_DEFAULT = 600.0
SERVED = ("diagnose",)
#: environment read while the libraries load (numba's and matplotlib's configuration, thread pools, locale)
KEY_ENV = ("CALIB_", "NUMBA_", "MPL", "PYTHON", "OMP_", "OPENBLAS_", "MKL_", "NUMEXPR_", "LC_", "LANG", "TZ",
           "HOME", "XDG_", "VIRTUAL_ENV", "LD_", "TMP", "TEMP")
_LEN = struct.Struct("<I")
_SIGNALS = {"SIGINT": signal.SIGINT, "SIGTERM": signal.SIGTERM}
_HELD: list = []   # in the server: its lock file's descriptor


def enabled() -> bool:
    return hasattr(os, "fork") and hasattr(socket, "AF_UNIX") and hasattr(socket, "send_fds") and \
        os.environ.get(ENV, "on").strip().lower() not in ("off", "0", "no", "false")


def served(argv) -> bool:
    """Whether ``calib ARGV`` is a command a server runs (its first word ``diagnose``)."""
    words = [w for w in argv if not w.startswith("-")]
    return bool(words) and words[0] in SERVED and not {"-h", "--help", "--version"} & set(argv)


def folder() -> Path | None:
    """The user's private folder of server sockets, or None when it is not private (then no server is used)."""
    base = os.environ.get("XDG_RUNTIME_DIR") or tempfile.gettempdir()
    if len(os.fsencode(base)) > 60:   # a socket's path has at most 107 bytes
        base = tempfile.gettempdir()
    d = Path(base) / f"calib-{os.getuid()}"
    try:
        d.mkdir(mode=0o700, exist_ok=True)
        st = d.lstat()
    except OSError:
        return None
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o077:
        return None
    return d


def key() -> str:
    """What the warmed state depends on (module docstring): equal keys, same code and import-time settings."""
    import calib

    h = hashlib.sha256()
    search = sys.path[1:]   # [0] is the script's folder or the working directory: not the same for every launcher
    h.update(repr((sys.executable, sys.version, search, os.getuid(), sys.flags, sys.warnoptions,
                   sys._xoptions)).encode())
    for p in search:
        with contextlib.suppress(OSError):
            h.update(f"{p}:{os.stat(p).st_mtime_ns}\n".encode())
    pkg = Path(calib.__file__).resolve().parent
    for root, dirs, files in os.walk(pkg):
        dirs[:] = sorted(d for d in dirs if d != "__pycache__")
        for f in sorted(files):
            p = os.path.join(root, f)
            with contextlib.suppress(OSError):
                st = os.stat(p)
                h.update(f"{p}:{st.st_size}:{st.st_mtime_ns}\n".encode())
    for k in sorted(os.environ):
        if k.startswith(KEY_ENV) and not k.startswith(ENV):
            h.update(f"{k}={os.environ[k]}\n".encode())
    return h.hexdigest()[:24]


def _paths(k: str, d: Path):
    return d / f"srv-{k}.sock", d / f"srv-{k}.lock"


def _current():
    """``(key, socket path, lock path)`` of this process's code, or None when no server may be used."""
    d = folder() if enabled() else None
    if d is None:
        return None
    k = key()
    return (k, *_paths(k, d))


# ------------------------------------------------------------------------------------------------ the command side


def run_served(argv) -> int | None:
    """Run ``calib ARGV`` in a warm server and return its exit code; None when no server took it (then the caller
    runs the command itself: nothing of it has run)."""
    where = _current() if served(argv) else None
    if where is None:
        return None
    k, path, _ = where
    try:
        for fd in (0, 1, 2):
            os.fstat(fd)
    except OSError:   # a closed standard stream cannot be handed over
        return None
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        return _hand_over(s, path, k, argv)
    except KeyboardInterrupt:   # Ctrl-C before the run took over (a run already started sees the socket close)
        s.close()
        cli._not_started()
        return EXIT_SIGINT


def _hand_over(s, path, k, argv) -> int | None:
    try:
        s.settimeout(10.0)   # a server that does not take the command at once (stopped, stuck): run it cold
        s.connect(str(path))
        ignored = [n for n, sig in _SIGNALS.items() if signal.getsignal(sig) is signal.SIG_IGN]
        umask = os.umask(0)
        os.umask(umask)
        req = json.dumps({"key": k, "argv": list(argv), "cwd": os.getcwd(), "env": dict(os.environ),
                          "umask": umask, "ignored": ignored}).encode()
        socket.send_fds(s, [_LEN.pack(len(req))], [0, 1, 2])
        s.sendall(req)
        if s.recv(1) != b"A":   # a server of other code, or one that ended: nothing ran
            s.close()
            return None
        s.settimeout(None)
    except OSError:
        s.close()
        return None
    return _wait(s)


def _wait(s) -> int:
    """The run is under way in the server: pass SIGINT / SIGTERM on, wait for its exit code."""
    sent = []

    def forward(signum, frame):
        sent.append(signum)
        with contextlib.suppress(OSError):
            s.send(b"I" if signum == signal.SIGINT else b"T")

    for sig in _SIGNALS.values():
        if signal.getsignal(sig) is not signal.SIG_IGN:
            signal.signal(sig, forward)
    buf = b""
    while not buf.endswith(b"\n"):
        try:
            b = s.recv(64)
        except OSError:
            b = b""
        if not b:
            break
        buf += b
    s.close()
    for sig in _SIGNALS.values():   # the outcome is decided (as a cold command after its outcome)
        signal.signal(sig, signal.SIG_IGN)
    if buf.endswith(b"\n"):
        return int(buf[1:].strip())
    if sent:   # the run was killed by the signal passed on (it came before its handlers): so is the command
        signal.signal(sent[0], signal.SIG_DFL)
        os.kill(os.getpid(), sent[0])
    print("calib diagnose: the server process running the command ended without an exit code (killed?); "
          "outputs it had not finished are not written -- fix: run it again, or with CALIB_SERVER=off",
          file=sys.stderr)
    return EXIT_INTERNAL


def idle_seconds() -> float:
    try:
        v = float(os.environ.get(IDLE_ENV, "") or IDLE_DEFAULT)
    except ValueError:
        v = IDLE_DEFAULT
    return v if v > 0 else IDLE_DEFAULT


def start_background() -> bool:
    """Start a server for the current key unless one runs (or starts) already; never waits, never fails. True
    when one was started."""
    where = _current()
    if where is None or _locked(where[2]):
        return False
    k = where[0]
    import subprocess

    try:
        subprocess.Popen([sys.executable, "-m", "calib.cli.server", "serve", k], stdin=subprocess.DEVNULL,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
                         close_fds=True)
    except OSError:
        return False
    return True


def _locked(lock: Path) -> bool:
    """Whether a server holds ``lock`` (it keeps it locked while it lives)."""
    import fcntl

    try:
        fd = os.open(lock, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        return False
    except OSError:
        return True
    finally:
        os.close(fd)


# ------------------------------------------------------------------------------------------------ the server


def warm() -> None:
    """Load what every ``calib diagnose`` loads: the command line, the diagnosis and its readers, numba's cached
    kernels of the loaded calib modules (all cached signatures), and matplotlib with its fonts (the figures are
    drawn by a helper forked from the run, which inherits them). Caches only: a run gives the same bytes."""
    import calib.cli
    import calib.cli.formats  # noqa: F401 - the parser registers its sub-commands on every run
    import calib.diagnosis  # noqa: F401
    import calib.io.recording  # noqa: F401
    import calib.signal.plausibility  # noqa: F401

    _load_numba_caches()
    from calib.figures import diagnosis as figs

    figs.warm_up()


def _load_numba_caches() -> None:
    from numba.core.registry import CPUDispatcher

    for name, mod in sorted(sys.modules.items()):
        if not name.startswith("calib.") or mod is None:
            continue
        for obj in list(vars(mod).values()):
            if not isinstance(obj, CPUDispatcher) or getattr(obj, "_cache", None) is None:
                continue
            with contextlib.suppress(Exception):   # a cache numba no longer reads: compiled on first use as usual
                index = obj._cache._cache_file._load_index()
                for entry in index:
                    if entry == obj._cache._index_key(entry[0], obj.targetctx.codegen()):
                        obj.compile(entry[0])


def serve(k: str) -> int:
    """The server's life: lock, warm, listen, fork a run per request; ends when idle or when its code changed."""
    import fcntl
    import select

    d = folder()
    if d is None or k != key():
        return 0
    path, lock = _paths(k, d)
    lock_fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(lock_fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:   # another server of this key runs or starts
        return 0
    os.ftruncate(lock_fd, 0)
    os.write(lock_fd, f"{os.getpid()}\n".encode())
    _HELD[:] = [lock_fd]   # a run closes it: only the server holds the lock

    def stop(signum, frame):
        raise SystemExit(0)

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    idle = idle_seconds()
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    tmp = d / f".{os.getpid()}.sock"
    ino = None
    try:
        warm()
        import gc

        gc.collect()
        gc.freeze()   # the warmed objects are never collected: no run traverses (and copies) them at each collection
        sock.bind(str(tmp))
        sock.listen(16)
        os.replace(tmp, path)   # clients see the socket only once the state is warm
        ino = path.stat().st_ino
        signal.signal(signal.SIGCHLD, signal.SIG_IGN)   # runs are reaped by the kernel
        last = time.monotonic()
        while True:
            ready, _, _ = select.select([sock], [], [], min(30.0, idle))
            if not ready:
                if time.monotonic() - last > idle or key() != k:
                    break
                continue
            conn, _ = sock.accept()
            last = time.monotonic()
            if not _take(conn, sock, k):
                break
    finally:
        with contextlib.suppress(OSError):
            if ino is not None and path.stat().st_ino == ino:
                path.unlink()
        with contextlib.suppress(OSError):
            tmp.unlink()
        sock.close()
        with contextlib.suppress(OSError):   # the lock file goes too, unless a newer server made its own
            if lock.stat().st_ino == os.fstat(lock_fd).st_ino:
                lock.unlink()
        os.close(lock_fd)
    return 0


def _take(conn, sock, k: str) -> bool:
    """One request: fork its run. False when this server should end (its code changed)."""
    fds = []
    try:
        creds = conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
        if struct.unpack("3i", creds)[1] != os.getuid():
            return True
        conn.settimeout(10.0)
        head, fds, _, _ = socket.recv_fds(conn, _LEN.size, 3)
        n = _LEN.unpack(head)[0] if len(head) == _LEN.size else 0
        body = b""
        while len(body) < n:
            b = conn.recv(n - len(body))
            if not b:
                return True
            body += b
        req = json.loads(body)
        if req.get("key") != k or len(fds) != 3:
            return key() == k
        conn.settimeout(None)
        if os.fork() == 0:
            sock.close()
            for fd in _HELD:
                os.close(fd)
            _run(conn, fds, req)   # never returns
        return True
    except (OSError, ValueError):
        return True
    finally:
        for fd in fds:
            with contextlib.suppress(OSError):
                os.close(fd)
        conn.close()


def _run(conn, fds, req) -> None:
    """In the forked copy: become the command (its streams, folder, environment, umask, signal dispositions) and
    run :func:`calib.cli.main` exactly as the ``calib`` command does; report the exit code and end."""
    code = EXIT_INTERNAL
    try:
        signal.signal(signal.SIGCHLD, signal.SIG_DFL)
        signal.signal(signal.SIGHUP, signal.SIG_DFL)
        for name, sig in _SIGNALS.items():   # as a new Python process finds them
            signal.signal(sig, signal.SIG_IGN if name in req["ignored"] else
                          signal.default_int_handler if sig == signal.SIGINT else signal.SIG_DFL)
        os.setsid()   # apart from the server's session: the server's end leaves a run alone
        for i, fd in enumerate(fds):
            os.dup2(fd, i)
            os.close(fd)
        fds.clear()
        os.chdir(req["cwd"])
        os.environ.clear()
        os.environ.update(req["env"])
        tempfile.tempdir = None   # looked up again from the command's environment
        os.umask(req["umask"])
        sys.stdout.reconfigure(line_buffering=os.isatty(1))
        sys.argv = ["calib", *req["argv"]]
        conn.sendall(b"A")
        _watch(conn)
        code = cli.main(req["argv"], exiting=True)
    except SystemExit as exc:   # argparse's usage errors and --help
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        if isinstance(exc.code, str):
            print(exc.code, file=sys.stderr)
    except KeyboardInterrupt:   # a Ctrl-C before the command's own handlers were in place
        cli._not_started()
        code = EXIT_SIGINT
    except BaseException:  # noqa: BLE001 - the command reports a run without an exit code
        code = EXIT_INTERNAL
    finally:
        with contextlib.suppress(Exception):
            sys.stdout.flush()
            sys.stderr.flush()
        with contextlib.suppress(OSError):
            conn.sendall(b"X%d\n" % code)
        os._exit(code)


def _watch(conn) -> None:
    """A thread that turns the command's messages into signals of this run: I -> SIGINT, T -> SIGTERM, and the
    command gone (connection closed) -> SIGTERM."""
    import threading

    def loop():
        while True:
            try:
                b = conn.recv(1)
            except OSError:
                b = b""
            if b == b"I":
                os.kill(os.getpid(), signal.SIGINT)
            elif b == b"T" or not b:
                os.kill(os.getpid(), signal.SIGTERM)
                if not b:
                    return

    threading.Thread(target=loop, daemon=True).start()


# ------------------------------------------------------------------------------------------------ status / stop


def servers() -> list:
    """``(key, pid, current)`` of the servers running for this user."""
    d = folder()
    out = []
    if d is None:
        return out
    k = key()
    for lock in sorted(d.glob("srv-*.lock")):
        if not _locked(lock):
            continue
        with contextlib.suppress(OSError, ValueError):
            out.append((lock.stem[4:], int(lock.read_text().split()[0]), lock.stem[4:] == k))
    return out


def stop_all() -> int:
    n = 0
    for _, pid, _ in servers():
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGTERM)
            n += 1
    return n


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["serve"] and len(argv) == 2:
        return serve(argv[1])
    print("usage: python -m calib.cli.server serve KEY   (started by 'calib diagnose'; see 'calib server')",
          file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())

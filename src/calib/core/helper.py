"""A helper process beside one command: work that needs none of the command's state runs on the second core.

``calib diagnose`` spends most of its first second importing the numerical libraries; meanwhile a forked helper
checks the input files sample by sample, imports the plotting library, and later draws the figures -- two at a
time, one in a forked grandchild; ``calib navigate`` has its helper check every sample of the recording while it
navigates (its output is written once that check passed). The command's own process owns every output file:

* the helper writes nothing: a job returns its value (a figure as PNG bytes) to the command, which writes it
  atomically as before (:mod:`calib.io.atomic`), so an interruption leaves no partial file whatever the helper
  was doing;
* a job's printed output is captured and returned with its value; the command prints it where it would have
  appeared, so the terminal shows the same lines in the same order;
* an exception in a job is raised again in the command (its traceback text attached as a note), so errors keep
  their exit codes; a helper that died raises :class:`HelperError`, on which the callers do the work themselves
  (``calib diagnose`` checks its inputs and draws its figures in its own process);
* the helper runs in its own process group (a Ctrl-C at the terminal reaches the command only) and ends with
  the command: :meth:`Helper.close` terminates the group and reaps the helper on every path, including
  SIGINT / SIGTERM of the command; if the command itself is killed, the helper sees its request pipe close and
  exits.

Jobs are named ``"module:function"`` and their arguments are pickled (plain data, not the command's objects). The
helper runs a job itself, in the order submitted (an input check; the plotting library's warm-up, which every later
job inherits), or -- submitted ``beside=True`` -- in a process forked from it while it goes on reading requests (a
figure: the residual figure starts as soon as its data are known, not behind the Allan figure still being drawn). A
job beside starts when the helper takes it, after the jobs before it that the helper runs itself. The reply pipes
hold a whole figure (1 MiB where Linux allows), so a job never waits for the command to read its reply.
``CALIB_HELPER=off`` (or a platform without ``os.fork``) runs everything in the command's process, as before.
"""
from __future__ import annotations

import contextlib
import fcntl
import importlib
import io
import os
import pickle
import select
import signal
import struct
import sys
import traceback

ENV = "CALIB_HELPER"
_HEADER = struct.Struct("<Q")
_CURRENT: list = [None]
_SERVING: list = []   # in the helper: its two pipe ends (a grandchild closes them)


class HelperError(RuntimeError):
    """The helper process ended without answering (killed, out of memory): a bug or the environment."""


def enabled() -> bool:
    return hasattr(os, "fork") and os.environ.get(ENV, "on").strip().lower() not in ("off", "0", "no", "false")


def current() -> "Helper | None":
    """The helper of the running command, or None (then the caller does the work itself)."""
    h = _CURRENT[0]
    return h if h is not None and h.alive else None


@contextlib.contextmanager
def running():
    """A :class:`Helper` for the block (None when disabled); closed and reaped when the block ends, however."""
    if not enabled() or _CURRENT[0] is not None:
        yield None
        return
    try:
        h = Helper()
    except OSError:   # no process to spare (fork refused): the command does everything itself
        yield None
        return
    _CURRENT[0] = h
    try:
        yield h
    finally:
        _CURRENT[0] = None
        h.close()


# ------------------------------------------------------------------------------------------------ wire format


#: the capacity asked for the reply pipes: a figure's PNG (80-200 kB) fits, so whoever answers never blocks until
#: the command reads (the default 64 kB made the helper wait for the command to finish its analysis)
PIPE_BYTES = 1 << 20


def _pipe():
    """``os.pipe()`` with :data:`PIPE_BYTES` of capacity where the platform allows (Linux ``F_SETPIPE_SZ``, up to
    ``/proc/sys/fs/pipe-max-size``); the default capacity otherwise (only slower)."""
    r, w = os.pipe()
    with contextlib.suppress(AttributeError, OSError):
        fcntl.fcntl(w, fcntl.F_SETPIPE_SZ, PIPE_BYTES)
    return r, w


def _write_all(fd, data: bytes) -> None:
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        view = view[n:]


def _read_exact(fd, n: int) -> bytes | None:
    chunks, left = [], n
    while left:
        b = os.read(fd, min(left, 1 << 20))
        if not b:
            return None
        chunks.append(b)
        left -= len(b)
    return b"".join(chunks)


def _frame(obj) -> bytes:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    return _HEADER.pack(len(data)) + data


def _recv(fd):
    head = _read_exact(fd, _HEADER.size)
    if head is None:
        return None
    body = _read_exact(fd, _HEADER.unpack(head)[0])
    return None if body is None else pickle.loads(body)


# ------------------------------------------------------------------------------------------------ the command side


class Helper:
    """The command's handle on its helper process (started by the constructor)."""

    def __init__(self):
        req_r, req_w = os.pipe()
        rep_r, rep_w = _pipe()
        sys.stdout.flush()
        sys.stderr.flush()
        # no signal between the fork and the helper's own dispositions: a Ctrl-C there must not run the command's
        # handler in the helper (its KeyboardInterrupt would unwind the command's code in the forked copy)
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
        try:
            pid = os.fork()
            if pid == 0:   # the helper: never returns
                try:
                    _CURRENT[0] = None
                    os.close(req_w)
                    os.close(rep_r)
                    _serve(req_r, rep_w, mask)
                finally:
                    os._exit(1)
            with contextlib.suppress(OSError):
                os.setpgid(pid, pid)   # (the helper does it too: whichever runs first)
            os.close(req_r)
            os.close(rep_w)
            self.pid, self._w, self._r = pid, req_w, rep_r
            self._next, self._replies, self.alive = 0, {}, True
        except BaseException:
            for fd in (req_r, req_w, rep_r, rep_w):
                with contextlib.suppress(OSError):
                    os.close(fd)
            raise
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)

    def submit(self, calls, *, beside: bool = False) -> int:
        """Queue ``calls`` -- a list of ``(target, args)``, run at the same time when several -- and return the job id
        whose :meth:`result` is the list of their values. ``beside``: run in a process forked from the helper when the
        helper takes it (after the jobs before it), while the helper takes the next jobs (for work that changes nothing
        the later jobs need, e.g. a figure); else by the helper itself after the jobs before it. Replies arriving
        meanwhile are read (no deadlock on full pipes)."""
        if not self.alive:
            raise HelperError("the helper process has ended")
        jid = self._next
        self._next += 1
        data = memoryview(_frame((jid, [(t, tuple(a)) for t, a in calls], bool(beside))))
        while data:
            rd, wr, _ = select.select([self._r], [self._w], [])
            if rd:
                self._read_one()
            if wr:
                try:
                    n = os.write(self._w, data[:1 << 16])
                except BrokenPipeError:
                    status = self.close()
                    raise HelperError(f"the helper process has ended ({_describe(status)})") from None
                data = data[n:]
        return jid

    def result(self, jid):
        """The values of job ``jid`` in the order of its calls (waits). A job's printed output is printed here;
        its exception is raised here."""
        while jid not in self._replies:
            self._read_one()
        outcomes = self._replies.pop(jid)
        values = []
        for ok, value, text in outcomes:
            if text:
                sys.stdout.write(text)
            if not ok:
                raise _exception(value)
            values.append(value)
        return values

    def run(self, target, *args):
        """One call, waited for."""
        return self.result(self.submit([(target, args)]))[0]

    def _read_one(self):
        msg = _recv(self._r)
        if msg is None:
            status = self.close()
            raise HelperError(f"the helper process ended without answering ({_describe(status)})")
        self._replies[msg[0]] = msg[1]

    def close(self):
        """End the helper (and any grandchild drawing for it) and reap it; returns its wait status."""
        if not self.alive:
            return self._status
        self.alive = False
        for fd in (self._w, self._r):
            with contextlib.suppress(OSError):
                os.close(fd)
        for kill in (os.kill, os.killpg):   # the helper, then its group (a grandchild drawing for it)
            with contextlib.suppress(ProcessLookupError, PermissionError):
                kill(self.pid, signal.SIGTERM)
        while True:
            try:
                _, self._status = os.waitpid(self.pid, 0)
                break
            except InterruptedError:
                continue
            except ChildProcessError:
                self._status = None
                break
        return self._status


def _describe(status) -> str:
    if status is None:
        return "already reaped"
    if os.WIFSIGNALED(status):
        return f"killed by signal {os.WTERMSIG(status)}"
    return f"exit status {os.WEXITSTATUS(status)}"


def _exception(value) -> BaseException:
    blob, name, text, tb = value
    exc = None
    if blob is not None:
        with contextlib.suppress(Exception):
            exc = pickle.loads(blob)
    if not isinstance(exc, BaseException):
        exc = HelperError(f"{name}: {text}")
    with contextlib.suppress(Exception):
        exc.add_note("raised in the helper process:\n" + tb)
    return exc


# ------------------------------------------------------------------------------------------------ the helper side


def _serve(req_r, rep_w, mask):
    code = 0
    _SERVING[:] = [req_r, rep_w]
    beside = {}   # read end of a job run beside -> (its process, job id, number of calls)
    try:
        with contextlib.suppress(OSError):
            os.setpgid(0, 0)   # its own group: the terminal's Ctrl-C goes to the command, which ends the helper
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        open_ = True
        while open_ or beside:
            ready, _, _ = select.select(([req_r] if open_ else []) + list(beside), [], [])
            for fd in ready:
                if fd != req_r:   # a job run beside has answered (or died): its reply goes to the command
                    pid, jid, ncalls = beside.pop(fd)
                    _write_all(rep_w, _reply_of(fd, pid, jid, ncalls))
                    continue
                msg = _recv(req_r)
                if msg is None:   # the command closed its end (or died): nothing more to take
                    open_ = False
                    continue
                jid, calls, aside = msg
                if aside:
                    fd_kid, pid = _start_beside(calls, jid, beside)
                    beside[fd_kid] = (pid, jid, len(calls))
                else:
                    _write_all(rep_w, _frame((jid, _run_calls(calls))))
    except BaseException:  # noqa: BLE001 - the command sees the pipe close and reports it
        code = 1
    finally:
        os._exit(code)


def _fork_answering(produce, also_close=()):
    """Fork a process that writes one frame -- the value of ``produce()`` -- to a pipe of its own and exits; returns
    (the pipe's read end, its pid), collected by :func:`_answer_of`. It closes the helper's request and reply pipes
    (and ``also_close``): only the helper writes to the command."""
    r, w = _pipe()
    pid = os.fork()
    if pid == 0:
        code = 0
        try:
            for fd in [r, *_SERVING, *also_close]:
                os.close(fd)
            _SERVING[:] = []
            _write_all(w, _frame(produce()))
        except BaseException:  # noqa: BLE001 - the helper sees the pipe close
            code = 1
        finally:
            os._exit(code)
    os.close(w)
    return r, pid


def _answer_of(r, pid):
    """(the frame a process of :func:`_fork_answering` wrote, as bytes -- None when it ended without one --, its
    wait status); the pipe closed, the process reaped."""
    head = _read_exact(r, _HEADER.size)
    body = None if head is None else _read_exact(r, _HEADER.unpack(head)[0])
    os.close(r)
    _, status = os.waitpid(pid, 0)
    return (None if body is None else head + body), status


def _start_beside(calls, jid, beside):
    """The process of a job run beside the helper (:func:`_fork_answering`): its reply frame, which the helper
    forwards (:func:`_reply_of`)."""
    return _fork_answering(lambda: (jid, _run_calls(calls)), also_close=beside)


def _reply_of(fd, pid, jid, ncalls) -> bytes:
    """The reply frame a job run beside wrote (forwarded as it is), or one naming how its process ended."""
    frame, status = _answer_of(fd, pid)
    if frame is not None:
        return frame
    lost = (False, (None, "HelperError", f"the process of job {jid} ended without answering ({_describe(status)})",
                    ""), "")
    return _frame((jid, [lost] * ncalls))


def _run_calls(calls):
    """Run the calls, all but the first in forked grandchildren at the same time; outcomes in call order."""
    kids = [_fork_answering(lambda target=target, args=args: _call(target, args)) for target, args in calls[1:]]
    out = [_call(*calls[0])] if calls else []
    for (target, _), (r, pid) in zip(calls[1:], kids):
        frame, status = _answer_of(r, pid)
        out.append(pickle.loads(frame[_HEADER.size:]) if frame is not None else
                   (False, (None, "HelperError", f"{target}: the drawing process ended without answering "
                                                 f"({_describe(status)})", ""), ""))
    return out


def _call(target, args):
    """(ok, value or exception record, printed text) of ``target(*args)``; stdout and stderr captured."""
    buf = io.StringIO()
    try:
        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
            mod, _, name = target.partition(":")
            fn = importlib.import_module(mod)
            for part in name.split("."):
                fn = getattr(fn, part)
            value = fn(*args)
        return True, value, buf.getvalue()
    except BaseException as exc:  # noqa: BLE001 - handed to the command, which raises it
        try:
            blob = pickle.dumps(exc, protocol=pickle.HIGHEST_PROTOCOL)
            pickle.loads(blob)
        except Exception:  # noqa: BLE001 - an exception that does not survive pickling: its text only
            blob = None
        return False, (blob, type(exc).__name__, " ".join(str(exc).split())[:300], traceback.format_exc()), \
            buf.getvalue()

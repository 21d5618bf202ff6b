"""Logging and progress for long stages (used by the workflow scripts and the CLI)."""
from __future__ import annotations

import contextlib
import logging
import sys
import time


@contextlib.contextmanager
def to_file(path):
    """Send stdout, stderr and the ``calib`` logger to ``path`` (a rule's ``log:``) for the block."""
    with open(path, "w", buffering=1) as fh:
        handler = logging.StreamHandler(fh)
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
        root = logging.getLogger("calib")
        root.addHandler(handler)
        root.setLevel(logging.INFO)
        with contextlib.redirect_stdout(fh), contextlib.redirect_stderr(fh):
            try:
                yield fh
            except BaseException:
                import traceback

                traceback.print_exc(file=fh)
                raise
            finally:
                root.removeHandler(handler)


#: ``calib --quiet``: no progress at all (errors, warnings and the promised output stay)
QUIET = False
#: seconds between the plain progress lines echoed to the terminal while a workflow rule logs to a file
ECHO_EVERY_S = 30.0


def set_quiet(quiet: bool = True) -> None:
    global QUIET
    QUIET = bool(quiet)


def _isatty(stream) -> bool:
    try:
        return bool(stream is not None and stream.isatty())
    except (AttributeError, ValueError):
        return False


class Progress:
    """Progress of a long stage, on standard error.

    * standard error is a terminal: a live ``tqdm`` bar;
    * otherwise (a rule's log file, a pipe): a plain line ``label  42% [#####.....] 12.3 s, eta 17.0 s`` at most
      every ``every_s`` seconds and at completion, so logs stay short; when a workflow rule sends its output to
      a log file (:func:`to_file`) and the terminal is still there, the same line is echoed to it every
      :data:`ECHO_EVERY_S` seconds, so a long rule is never silent on screen;
    * ``calib --quiet`` (:func:`set_quiet`): nothing.
    """

    def __init__(self, total, label="", every_s=2.0, stream=None, width=30):
        self.total, self.label, self.every, self.width = max(total, 1), label, every_s, width
        self.stream = stream
        self.t0 = time.perf_counter()
        self.last = self.last_echo = -1e9
        self.done = 0
        self._bar = None

    def _tqdm(self, stream):
        if self._bar is None:
            from tqdm import tqdm

            self._bar = tqdm(total=self.total, desc=self.label, file=stream, leave=True, dynamic_ncols=True,
                             unit_scale=self.total > 10_000)
        return self._bar

    def __call__(self, done=None, extra=""):
        self.done = self.done + 1 if done is None else done
        if QUIET:
            return
        stream = self.stream or sys.stderr
        if _isatty(stream):
            bar = self._tqdm(stream)
            bar.total = max(self.total, 1)
            bar.update(max(min(self.done, bar.total) - bar.n, 0))
            if extra:
                bar.set_postfix_str(str(extra), refresh=False)
            if self.done >= self.total:
                bar.close()
            return
        now = time.perf_counter()
        if now - self.last < self.every and self.done < self.total:
            return
        self.last = now
        frac = min(self.done / self.total, 1.0)
        el = now - self.t0
        eta = el / frac - el if frac > 0 else float("nan")
        bar = "#" * int(frac * self.width) + "." * (self.width - int(frac * self.width))
        line = f"{self.label} {100 * frac:5.1f}% [{bar}] {el:7.1f} s, eta {eta:7.1f} s {extra}"
        print(line, file=stream, flush=True)
        term = sys.__stderr__
        if term is not stream and _isatty(term) and (now - self.last_echo >= ECHO_EVERY_S or frac >= 1.0):
            self.last_echo = now
            print(line.rstrip(), file=term, flush=True)

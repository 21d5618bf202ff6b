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


class Progress:
    """A text progress bar for logs: ``label  42% [#####.....] 12.3 s, eta 17.0 s``.

    Prints at most every ``every_s`` seconds (and at completion), so logs stay short.
    """

    def __init__(self, total, label="", every_s=2.0, stream=None, width=30):
        self.total, self.label, self.every, self.width = max(total, 1), label, every_s, width
        self.stream = stream
        self.t0 = time.perf_counter()
        self.last = -1e9
        self.done = 0

    def __call__(self, done=None, extra=""):
        self.done = self.done + 1 if done is None else done
        now = time.perf_counter()
        if now - self.last < self.every and self.done < self.total:
            return
        self.last = now
        frac = min(self.done / self.total, 1.0)
        el = now - self.t0
        eta = el / frac - el if frac > 0 else float("nan")
        bar = "#" * int(frac * self.width) + "." * (self.width - int(frac * self.width))
        print(f"{self.label} {100 * frac:5.1f}% [{bar}] {el:7.1f} s, eta {eta:7.1f} s {extra}",
              file=self.stream or sys.stdout, flush=True)

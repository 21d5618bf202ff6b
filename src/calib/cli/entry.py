"""The ``calib`` command line: the same library functions as the workflow rules, for work on single files.

    calib simulate calibration OUT.nc [--config config/config.yaml] [--seed N]
    calib simulate navigation OUT.nc [--hours H] [--force]
    calib import SETTINGS.yaml OUT.nc [--topic /imu]
    calib noise RECORDING.nc [--out DIR] [--kalibr imu.yaml]
    calib export CALIBRATION --format imutk|imucal|json --out PATH
    calib apply CALIBRATION RECORDING.nc OUT.nc
    calib validate RECORDING.nc [--force]
    calib calibrate RECORDING.nc --out DIR [--quick] [--noise-record LONG_STATIC.nc]
    calib fieldcal RECORDING.nc [--settings S.yaml] [--out result.nc]
    calib navigate RECORDING.nc --out errors.nc [--calibration DIR/default_calibration.nc]
    calib diagnose RECORDING.nc --out DIR [--settings FILE.yaml|json] [--noise-record LONG_STATIC.nc] [--limits]

Every recording is checked before any fit (format, time coordinate, masked samples, and the physical
plausibility of its magnitudes for the declared units: calib.signal.plausibility; --force turns the
plausibility refusals into warnings), and every result before it is reported as a success.
"""
from __future__ import annotations

import argparse
import contextlib
import gc
import os
import signal
import sys
import tempfile
import time
import traceback
import warnings

import yaml

from calib import __version__
from calib.cli import apply, calibrate, diagnose, export, navigate, noise_terms, recordings, simulate
from calib.cli.shared import COMMAND_STDOUT, OutputClosed
from calib.core import progress
from calib.core.errors import (EXIT_CODES, EXIT_INPUT, EXIT_INTERNAL, EXIT_SIGINT, EXIT_SIGPIPE, CalibError,
                               ResultCheckError, Terminated, yaml_problem)


#: the command groups, in the order ``calib --help`` lists their sub-commands
COMMANDS = (simulate, recordings, calibrate, navigate, diagnose, noise_terms, export, apply)
EPILOG = "exit codes:\n" + "\n".join(f"  {code:3d}  {text}" for code, text in EXIT_CODES)


@contextlib.contextmanager
def _signals(exiting: bool = False):
    """SIGINT and SIGTERM raise KeyboardInterrupt / Terminated (the same clean path: atomic writers delete their
    temporary files); a second signal during the clean-up is ignored. Once a signal was handled, whatever the
    interrupted code raised instead of the interruption (an extension module interrupted while it loads reports an
    ImportError, a library may wrap it) leaves as that interruption; an exception without a signal stays itself.

    An interruption raised where Python cannot pass it on -- inside a ``__del__`` or a weakref callback, e.g. while
    llvmlite frees its objects during numba's cache loading -- would be printed as "Exception ignored ... Traceback"
    and lost, the command running on to its end. It is caught by :data:`sys.unraisablehook` instead (nothing
    printed) and raised again 10 ms later from a SIGALRM timer, where it can propagate; should that be impossible,
    the end of the block raises it.

    ``exiting``: the process ends right after the block (the ``calib`` command): SIGINT and SIGTERM are then left
    ignored instead of restored. The outcome is decided and written; while Python shuts down it resets its
    handlers to the default, so a Ctrl-C arriving then would kill the process silently (exit -2, no line said)."""
    received = []

    def interruption():
        return KeyboardInterrupt() if received[0] == signal.SIGINT else Terminated(received[0])

    def handler(signum, frame):
        for s in (signal.SIGINT, signal.SIGTERM):
            signal.signal(s, signal.SIG_IGN)
        received.append(signum)
        raise interruption()

    def again(signum, frame):
        raise interruption()

    previous_hook = sys.unraisablehook
    rearm = hasattr(signal, "setitimer") and hasattr(signal, "SIGALRM")

    def unraisable(info):
        if received and isinstance(info.exc_value, KeyboardInterrupt):   # our interruption, swallowed
            if rearm:
                signal.setitimer(signal.ITIMER_REAL, 0.01)
            return
        previous_hook(info)

    old = {}
    with contextlib.suppress(ValueError):   # not the main thread: leave the handlers alone
        for s in (signal.SIGINT, signal.SIGTERM):
            if signal.getsignal(s) is not signal.SIG_IGN:
                old[s] = signal.signal(s, handler)
        if old and rearm:
            old[signal.SIGALRM] = signal.signal(signal.SIGALRM, again)
    if old:
        sys.unraisablehook = unraisable
    try:
        yield
        if received:   # swallowed and not raised again: the work went on to its end, still it was interrupted
            raise interruption()
    except Exception as exc:  # noqa: BLE001 - what an interrupted library raised is the interruption
        if not received:
            raise
        raise interruption() from exc
    finally:
        if old:
            sys.unraisablehook = previous_hook
            if rearm:
                signal.setitimer(signal.ITIMER_REAL, 0)
        for s, h in old.items():
            signal.signal(s, signal.SIG_IGN if exiting and s in (signal.SIGINT, signal.SIGTERM) else h)


def _say(text):
    """One line on standard error; a file name that was not valid UTF-8 (lone surrogates) shows escaped, as
    Python's own stderr would show it, whatever the stream's error handler (a capture)."""
    text = str(text).encode("utf-8", "backslashreplace").decode("utf-8")
    print(" ".join(text.split()) if "\n" in text else text, file=sys.stderr)


def _not_started(sig: str = "SIGINT") -> None:
    """The one line of an interrupt that came before the command started (while the sub-commands load): nothing
    was written."""
    _say(f"calib: interrupted by {sig}; nothing written")


def _os_message(exc: OSError) -> str:
    where = f"{exc.filename}: " if exc.filename else ""
    return f"{where}{exc.strerror or exc}"


def _internal_error(name, exc) -> int:
    """One line on the terminal; the traceback in a log file in the system temporary folder."""
    text = " ".join(f"{type(exc).__name__}: {exc}".split())[:300]
    try:
        fd, log = tempfile.mkstemp(prefix="calib-error-", suffix=".log")
        with os.fdopen(fd, "w") as fh:
            fh.write(f"{name} ({' '.join(sys.argv)}) at {time.strftime('%Y-%m-%d %H:%M:%S')}\n")
            fh.write(traceback.format_exc())
        where = f"traceback in {log}"
    except OSError:
        where = "no log file could be written"
    _say(f"{name}: internal error: {text} ({where}; please report it)")
    return EXIT_INTERNAL


def _output_closed() -> int:
    """Standard output from now on goes nowhere (Python's own flush at the exit would fail on the closed pipe
    again and print a message); the command stops silently with 141, as a shell reports a command killed by
    SIGPIPE -- not 2, which would blame the input."""
    with contextlib.suppress(OSError, ValueError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    return EXIT_SIGPIPE


def _one_line_warning(message, category, filename, lineno, line=None):
    return f"warning: {' '.join(str(message).split())}\n"


def _dispatch(a, exiting: bool = False) -> int:
    """Run the sub-command and map every outcome to the exit-code contract (calib.core.errors.EXIT_CODES)."""
    name = f"calib {a.cmd}"
    progress.set_quiet(getattr(a, "quiet", False))
    warnings.formatwarning = _one_line_warning
    COMMAND_STDOUT[0] = sys.stdout
    chatter = open(os.devnull, "w") if getattr(a, "quiet", False) else sys.stderr
    try:
        with _signals(exiting), contextlib.redirect_stdout(chatter):
            code = a.fn(a)
        return code or 0
    except OutputClosed:
        return _output_closed()
    except KeyboardInterrupt as exc:
        sig = "SIGTERM" if isinstance(exc, Terminated) else "SIGINT"
        _say(f"{name}: interrupted by {sig}; no partial output left, earlier outputs kept")
        return getattr(exc, "exit_code", EXIT_SIGINT)
    except ResultCheckError as exc:
        _say(f"{name}: result check failed: {exc}")
        return exc.exit_code
    except CalibError as exc:
        _say(f"{name}: error: {exc}")
        return exc.exit_code
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{mark.name}: line {mark.line + 1}: " if mark is not None else ""
        _say(f"{name}: error: {where}{yaml_problem(exc)}")
        return EXIT_INPUT
    except (ValueError, OSError, MemoryError) as exc:  # RecordingError and friends carry file, field and fix
        text = _os_message(exc) if isinstance(exc, OSError) else ("not enough memory" if isinstance(exc, MemoryError)
                                                                  else str(exc))
        _say(f"{name}: error: {text}")
        return EXIT_INPUT
    except Exception as exc:  # noqa: BLE001 - anything else is a bug: one line, the traceback in a log
        return _internal_error(name, exc)
    finally:
        COMMAND_STDOUT[0] = None
        if chatter is not sys.stderr:
            chatter.close()


def main(argv=None, *, exiting: bool = False):
    p = argparse.ArgumentParser(prog="calib", description=__doc__, epilog=EPILOG,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"calib {__version__}")
    p.add_argument("-q", "--quiet", action="store_true",
                   help="no progress and no informational lines (errors, warnings and the result stay)")
    sub = p.add_subparsers(dest="cmd", required=True)
    for module in COMMANDS:
        module.register(sub)
    try:
        with _signals():   # an interrupt while the sub-commands load: the same one line as during a command
            a = p.parse_args(argv)   # argparse's own usage errors exit 2
    except KeyboardInterrupt as exc:
        _not_started("SIGTERM" if isinstance(exc, Terminated) else "SIGINT")
        return getattr(exc, "exit_code", EXIT_SIGINT)
    return _dispatch(a, exiting)


def run():
    """The ``calib`` command (``python -m calib.cli`` too): :func:`main`, then the process ends with its exit code;
    an interrupt after the outcome is decided changes nothing (:func:`_signals`, ``exiting``)."""
    code = main(sys.argv[1:], exiting=True)
    # The interpreter shuts down as usual (exit handlers, module teardown); only the cyclic garbage collector is
    # told to leave the objects alive now alone. Its passes over the ~180 000 objects of numpy, scipy, numba and
    # matplotlib during the teardown cost 0.3-0.45 s of CPU after a cold `calib diagnose` (measured: the same run
    # with and without gc.freeze(), 2.9-3.1 against 2.6-2.8 s CPU); the memory goes back to the system either way.
    gc.freeze()
    sys.exit(code)

"""Atomic file writing: every product ``calib`` writes appears under its final name complete, or not at all.

A product is written to a unique temporary name in its own folder (``.NAME.XXXX.part``) and renamed over the
final name only when complete (``os.replace`` is atomic within a file system). On any error, including
``KeyboardInterrupt``, the temporary file is removed and the previous product, if any, is left untouched. The
temporary file gets the permissions a plain ``open`` would give (``0o666`` less the umask), not the ``0o600``
of :func:`tempfile.mkstemp`.

This is the one implementation: netCDF (:mod:`calib.io.netcdf`), figures (:mod:`calib.figures.output`),
JSON, Markdown and CSV products all go through :func:`atomic_path`. A command whose products
belong together writes them in one :func:`output_set`: they then appear all at once, or none does.
"""
from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import secrets
import threading
from pathlib import Path

import numpy as np


def utf8_name(path, what: str = "output") -> Path:
    """``path`` as a :class:`Path` if its name is valid UTF-8. The netCDF library opens and creates UTF-8 paths
    only, and Python keeps the bytes of a name that is not valid UTF-8 as lone surrogates: for such a name an
    :class:`calib.core.errors.InputError` naming the file and the fix, before any work is done, instead of the
    library's encoding error after it."""
    path = Path(path)
    try:
        str(path).encode("utf-8")
    except UnicodeEncodeError:
        from calib.core.errors import InputError   # here: that module loads yaml, this one is on every write path

        raise InputError(f"the name of the {what} (or of a folder on its path) is not valid UTF-8, and the netCDF "
                         "library reads and writes UTF-8 paths only", file=path,
                         fix="choose a name in valid UTF-8 (e.g. letters, digits, '-' and '_' only)") from None
    return path


def _temp_name(path: Path, suffix: str) -> Path:
    """A fresh name beside ``path`` (``.NAME.XXXXXXXX.part``); nothing is created."""
    return path.parent / f".{path.name}.{secrets.token_hex(4)}{suffix}"


def _create(tmp: Path) -> None:
    """Create the empty file ``tmp`` (not there before), with the permissions a plain ``open`` gives: ``0o666``
    less the umask."""
    os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))


@contextlib.contextmanager
def atomic_path(path, suffix: str = ".part", make_parents: bool = True):
    """Yield a temporary path beside ``path``; rename it to ``path`` on a clean exit, delete it otherwise. Inside
    an :func:`output_set` the rename waits for the end of the set.

    The temporary name is chosen before the file is created and the file created inside the block that removes it:
    an interruption at any point -- even between the creation and the line after it -- leaves no file behind."""
    path = Path(path)
    if make_parents:
        make_folder(path.parent)
    tmp = _temp_name(path, suffix)
    opened = _open_temps()
    try:
        while True:
            try:
                _create(tmp)
                break
            except FileExistsError:   # another writer's: the loop tries another name (never removes that file)
                tmp = _temp_name(path, suffix)
        opened.add(tmp)
        yield tmp
        opened.discard(tmp)
        _finish(tmp, path)
    except BaseException:
        opened.discard(tmp)
        _discard([tmp])
        raise


def make_folder(folder: Path) -> None:
    """``folder`` and its missing parents; inside an :func:`output_set` the folders made are noted, so that a set
    that ends without its products removes them again (when still empty)."""
    missing = []
    f = folder
    while not f.exists() and f != f.parent:
        missing.append(f)
        f = f.parent
    folder.mkdir(parents=True, exist_ok=True)
    made = getattr(_SETS, "folders", None)   # a list while an output set is open
    if made is not None:
        made.extend(missing)


def _finish(tmp, path) -> None:
    """The complete temporary file ``tmp`` becomes ``path``: now, or at the end of the open :func:`output_set` --
    but at once when ``path`` is itself the temporary file of an enclosing :func:`atomic_path` (a writer that
    writes atomically into another's temporary file: that one is then checked, e.g. :func:`calib.io.recording.write`
    validates it, before it becomes a product)."""
    pending = _open_set()
    if pending is None or Path(path) in _open_temps():
        os.replace(tmp, path)
    else:
        _discard([pending.pop(Path(path), None)])   # written twice in one set: the later content
        pending[Path(path)] = tmp


@contextlib.contextmanager
def scratch_folder(folder, make: bool = True):
    """``folder`` for one run's temporary files, made when missing (``make`` False: the run needs none, nothing is
    made) and removed again at the end of the block when the block made it and it is empty: a run leaves its
    products only (whatever a failed run left in it stays, for a look)."""
    folder = Path(folder)
    made = make and not folder.exists()
    if make:
        folder.mkdir(parents=True, exist_ok=True)
    try:
        yield folder
    finally:
        if made:
            with contextlib.suppress(OSError):
                folder.rmdir()


_SETS = threading.local()


def _open_temps() -> set:
    """This thread's temporary files of the :func:`atomic_path` blocks it is inside."""
    if not hasattr(_SETS, "temps"):
        _SETS.temps = set()
    return _SETS.temps


def _open_set() -> dict | None:
    """The pending ``{final path: temporary path}`` of this thread's open :func:`output_set`, or None."""
    return getattr(_SETS, "pending", None)


def _discard(paths) -> None:
    for p in paths:
        if p is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(p)


@contextlib.contextmanager
def output_set():
    """The products written in the block (through :func:`atomic_path`: every writer of this module, figures,
    netCDF) appear together when the block ends cleanly, or none of them does: a command's outputs -- e.g.
    ``calib diagnose``'s report.json, report.md and figures -- are never a mixture of one run's files and
    another's, or of a run that was interrupted. Until the end each product waits complete under its temporary
    name; on any error or interruption in the block the temporary files go and the previous products are left
    untouched. A set opened inside another joins it.

    The renames at the end run with SIGINT and SIGTERM held back (their Python handlers deferred: a KeyboardInterrupt
    between two renames would leave half a set); a signal that came meanwhile is raised again once every product
    is in place. A rename that fails (the name is a folder) leaves the products renamed before it and removes the
    rest (an error, as before). Folders made for the products inside the set are removed again, when still empty, if
    the set ends without its products."""
    if _open_set() is not None:
        yield
        return
    pending = _SETS.pending = {}
    folders = _SETS.folders = []
    came: list = []
    done = False
    try:
        try:
            yield
        finally:
            _SETS.pending = None
            _SETS.folders = None
        with _signals_held(came):
            for path, tmp in list(pending.items()):
                os.replace(tmp, path)
                del pending[path]
        done = True
    finally:
        _discard(pending.values())
        if not done:   # the folders the set made for its products, when nothing else went into them
            for f in sorted(folders, key=lambda f: len(f.parts), reverse=True):   # the deepest first
                with contextlib.suppress(OSError):
                    os.rmdir(f)
    if came:
        signal.raise_signal(came[0])


@contextlib.contextmanager
def _signals_held(came: list):
    """SIGINT / SIGTERM appended to ``came`` instead of handled for the block (Python runs its handlers in the main
    thread only: elsewhere nothing to hold)."""
    old = {}

    def hold(signum, frame):
        came.append(signum)

    try:
        if threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                h = signal.getsignal(s)
                if callable(h):   # a Python handler (ignored / default dispositions stay as they are)
                    old[s] = signal.signal(s, hold)
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


#: the encoding of every text product: UTF-8 whatever the locale (the same bytes everywhere); a character UTF-8
#: cannot hold -- a lone surrogate, which is how Python keeps a file name that was not valid UTF-8 -- is written as
#: its escape (``\\udcff``), as the terminal shows it, instead of failing half-way through a set of products
TEXT_ENCODING = {"encoding": "utf-8", "errors": "backslashreplace"}


def write_text(path, text: str, make_parents: bool = True) -> Path:
    """Write ``text`` to ``path`` atomically (:data:`TEXT_ENCODING`)."""
    path = Path(path)
    with atomic_path(path, make_parents=make_parents) as tmp:
        tmp.write_text(text, **TEXT_ENCODING)
    return path


def json_default(o):
    """JSON encoding of numpy scalars and arrays and of paths (non-finite floats become null)."""
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.floating):
        v = float(o)
        return v if math.isfinite(v) else None
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.bool_):
        return bool(o)
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o)}")


def strict_json(o):
    """A copy of ``o`` that is strict JSON: non-finite floats become None, numpy values plain Python, keys
    starting with ``_`` (private working values) are left out."""
    if isinstance(o, dict):
        return {str(k): strict_json(v) for k, v in o.items() if not str(k).startswith("_")}
    if isinstance(o, (list, tuple)):
        return [strict_json(v) for v in o]
    if isinstance(o, (float, np.floating)):
        v = float(o)
        return v if math.isfinite(v) else None
    if isinstance(o, np.ndarray):
        return strict_json(o.tolist())
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.bool_):
        return bool(o)
    return o


def write_json(obj, path, *, strict: bool = True, make_parents: bool = True) -> Path:
    """Write ``obj`` as indented JSON (``strict``: through :func:`strict_json`) atomically, newline-terminated."""
    if strict:
        obj = strict_json(obj)
    return write_text(path, json.dumps(obj, indent=2, default=json_default) + "\n", make_parents=make_parents)

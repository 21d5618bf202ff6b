"""Atomic file writing: every product ``calib`` writes appears under its final name complete, or not at all.

A product is written to a unique temporary name in its own folder (``.NAME.XXXX.part``) and renamed over the
final name only when complete (``os.replace`` is atomic within a file system). On any error, including
``KeyboardInterrupt``, the temporary file is removed and the previous product, if any, is left untouched. The
temporary file gets the permissions a plain ``open`` would give (``0o666`` less the umask), not the ``0o600``
of :func:`tempfile.mkstemp`.

This is the one implementation: netCDF (:mod:`calib.io.netcdf`), figures (:mod:`calib.figures.style`),
JSON, Markdown and CSV products all go through :func:`atomic_path`.
"""
from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
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


def umask() -> int:
    """The process umask (read without changing it for longer than one call)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def temp_path(path, suffix: str = ".part", make_parents: bool = True) -> Path:
    """A new empty file beside ``path`` with the permissions a plain ``open`` would give."""
    path = Path(path)
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix="." + path.name + ".", suffix=suffix, dir=path.parent)
    os.close(fd)
    os.chmod(tmp, 0o666 & ~umask())
    return Path(tmp)


@contextlib.contextmanager
def atomic_path(path, suffix: str = ".part", make_parents: bool = True):
    """Yield a temporary path beside ``path``; rename it to ``path`` on a clean exit, delete it otherwise."""
    path = Path(path)
    tmp = temp_path(path, suffix, make_parents)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise


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

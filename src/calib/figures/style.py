"""Deterministic figure output: the same data give byte-identical PNG, SVG and PDF files.

matplotlib writes creation dates into PDF and SVG and random ids into SVG; they are pinned here:
``svg.hashsalt`` fixed, ``metadata={'Date': None}`` for SVG, ``{'CreationDate': None}`` for PDF, and
``Software`` removed from PNG. Every figure the project writes goes through :func:`save`, which writes to a
temporary name and renames.
"""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

STYLE = {
    "svg.hashsalt": "calib",
    "figure.dpi": 100,
    "savefig.dpi": 120,
    "font.size": 9,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "path.simplify": False,
}
plt.rcParams.update(STYLE)

_META = {
    ".png": {"Software": None},
    ".svg": {"Date": None, "Creator": None},
    ".pdf": {"CreationDate": None, "ModDate": None, "Producer": None, "Creator": None},
}


def save(fig, path) -> Path:
    """Save ``fig`` to ``path`` (format from the suffix) deterministically and atomically; closes it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    suffix = path.suffix.lower()
    fd, tmp = tempfile.mkstemp(prefix="." + path.stem + ".", suffix=suffix, dir=path.parent)
    os.close(fd)
    from calib.io.netcdf import _umask

    os.chmod(tmp, 0o666 & ~_umask())
    try:
        with plt.rc_context(STYLE):
            fig.savefig(tmp, format=suffix[1:], metadata=_META.get(suffix))
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    finally:
        plt.close(fig)
    return path

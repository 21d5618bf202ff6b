"""Deterministic figure output: the same data give byte-identical PNG, SVG and PDF files.

matplotlib writes creation dates into PDF and SVG and random ids into SVG; they are pinned here:
``svg.hashsalt`` fixed, ``metadata={'Date': None}`` for SVG, ``{'CreationDate': None}`` for PDF, and
``Software`` removed from PNG. Every figure the project writes goes through :func:`save`, which writes to a
temporary name and renames.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from calib.io.atomic import atomic_path  # noqa: E402

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
    suffix = path.suffix.lower()
    try:
        with atomic_path(path, suffix=suffix) as tmp, plt.rc_context(STYLE):
            fig.savefig(tmp, format=suffix[1:], metadata=_META.get(suffix))
    finally:
        plt.close(fig)
    return path

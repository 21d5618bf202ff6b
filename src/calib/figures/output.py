"""Writing a rendered figure: what :func:`calib.figures.style.save` does after drawing, without matplotlib.

A figure rendered to bytes (:func:`calib.figures.style.render`) comes with the findings of
:func:`calib.figures.style.inspect`; :func:`write_rendered` treats the findings (:data:`CHECK_ENV`: printed, or in
strict mode refused before anything is written) and writes the file atomically.
"""
from __future__ import annotations

import os
from pathlib import Path

from calib.io.atomic import atomic_path

#: ``CALIB_FIGURE_CHECK=strict``: :func:`calib.figures.style.save` refuses a figure that fails
#: :func:`calib.figures.style.inspect` (the CI workflow runs so); ``warn`` (default): the problems are printed;
#: ``off``: not looked at.
CHECK_ENV = "CALIB_FIGURE_CHECK"


class FigureCheckError(ValueError):
    """A figure with empty panels, unlabelled axes or several series without a legend."""


def check_mode() -> str:
    return os.environ.get(CHECK_ENV, "warn").lower()


def report_problems(path, problems) -> None:
    """``problems`` of the figure for ``path``: raised in strict mode, else printed (one line each)."""
    path = Path(path)
    if problems and check_mode() == "strict":
        raise FigureCheckError(f"figure {path.name}: " + "; ".join(problems))
    for p in problems:
        print(f"figure {path.name}: {p}")


def write_rendered(path, data: bytes | None, problems) -> Path:
    """Write a figure rendered by :func:`calib.figures.style.render` to ``path`` as :func:`~calib.figures.style.save`
    would have: its problems reported first (strict mode: raised, nothing written), then the bytes atomically."""
    path = Path(path)
    report_problems(path, problems)
    with atomic_path(path, suffix=path.suffix.lower()) as tmp:
        tmp.write_bytes(data)
    return path

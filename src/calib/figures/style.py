"""Deterministic figure output: the same data give byte-identical PNG, SVG and PDF files.

matplotlib writes creation dates into PDF and SVG and random ids into SVG; they are pinned here:
``svg.hashsalt`` fixed, ``metadata={'Date': None}`` for SVG, ``{'CreationDate': None}`` for PDF, and
``Software`` removed from PNG. Every figure the project writes goes through :func:`save`: :func:`render` to bytes,
then :func:`calib.figures.output.write_rendered`, which writes to a temporary name and renames.
"""
from __future__ import annotations

import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib import ticker  # noqa: E402

from calib.figures.output import CHECK_ENV, FigureCheckError, check_mode, write_rendered  # noqa: E402,F401

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


def auto_log(ax, values, which="y", min_ratio=10.0) -> str:
    """Log scale on ``which`` axis only when the positive ``values`` span at least ``min_ratio`` (a log axis over
    206..213 has no tick labels and hides nothing); returns the scale chosen."""
    import numpy as np

    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    scale = "log" if v.size and v.min() > 0 and v.max() / v.min() >= min_ratio else "linear"
    (ax.set_yscale if which == "y" else ax.set_xscale)(scale)
    return scale


def _has_data(ax) -> bool:
    for line in ax.get_lines():
        if line.get_visible() and len(line.get_xdata()) > 0 and not _is_reference_line(line):
            return True
    for c in ax.collections:
        if c.get_visible() and (len(c.get_offsets()) > 0 or len(c.get_paths()) > 0):
            return True
    return bool(ax.images) or any(p.get_visible() for p in ax.patches) or bool(ax.tables)


def _is_reference_line(line) -> bool:
    """axhline/axvline: drawn in axes coordinates along one direction (a reference, not a data series)."""
    x, y = line.get_xdata(), line.get_ydata()
    return len(x) == 2 and (tuple(x) == (0, 1) or tuple(y) == (0, 1)) and line.get_transform() != line.axes.transData


def _series(ax):
    arts = [a for a in ax.get_lines() if a.get_visible() and len(a.get_xdata()) > 1 and not _is_reference_line(a)]
    arts += [c for c in ax.collections if c.get_visible() and len(c.get_offsets()) > 1]
    return arts


def _label_of(ax, which) -> bool:
    """The axis has a label, or a sharing neighbour / the figure carries one for it."""
    get = (lambda a: a.get_xlabel()) if which == "x" else (lambda a: a.get_ylabel())
    if get(ax).strip():
        return True
    shared = ax.get_shared_x_axes() if which == "x" else ax.get_shared_y_axes()
    if any(get(a).strip() for a in shared.get_siblings(ax)):
        return True
    sup = getattr(ax.figure, "_supxlabel" if which == "x" else "_supylabel", None)
    return bool(sup is not None and sup.get_text().strip())


def inspect(fig) -> list[str]:
    """What a reader would miss in ``fig``: empty panels (switch them off instead), axes without a label, several
    labelled series without a legend, several unlabelled series in a panel of a figure with no legend and no
    colour bar, a log axis over less than a factor of 2."""
    problems = []
    fig_legend = bool(fig.legends)
    legend_texts = {t.get_text() for lg in list(fig.legends) + [a.get_legend() for a in fig.axes if a.get_legend()]
                    for t in lg.get_texts()}
    colorbar = any(a.get_label() == "<colorbar>" for a in fig.axes)
    for i, ax in enumerate(fig.axes):
        if not ax.get_visible() or not ax.axison or ax.get_label() == "<colorbar>":
            continue
        name = f"panel {i + 1}" + (f" ('{ax.get_title()}')" if ax.get_title() else "")
        if not _has_data(ax):
            problems.append(f"{name} is empty (draw in it or switch it off)")
            continue
        for which in ("x", "y"):
            if not _label_of(ax, which):
                problems.append(f"{name} has no {which} label")
        series = _series(ax)
        labelled = {a.get_label() for a in series if not str(a.get_label()).startswith("_")}
        has_legend = ax.get_legend() is not None or fig_legend
        if len(labelled) >= 2 and not has_legend and not labelled <= legend_texts:
            problems.append(f"{name} draws {len(labelled)} labelled series without a legend")
        if len(series) >= 2 and not labelled and not has_legend and not legend_texts and not colorbar and not ax.texts:
            problems.append(f"{name} draws {len(series)} series, none labelled and no legend")
        for which, lim in (("x", ax.get_xlim()), ("y", ax.get_ylim())):
            scale = ax.get_xscale() if which == "x" else ax.get_yscale()
            lo, hi = sorted(lim)
            if scale == "log" and lo > 0 and hi / lo < 2.0:
                problems.append(f"{name}: log {which} axis over {lo:.4g}..{hi:.4g} (less than a factor 2: use linear)")
    return problems


def fixed_margins(fig, left: float, right: float, top: float, bottom: float, wspace: float = 0.0,
                  hspace: float = 0.0) -> None:
    """Place the axes of ``fig`` with margins given in inches (``wspace``/``hspace``: the gap between panels, in
    inches too). A layout of known text needs no measuring: ``tight_layout`` draws every tick label to measure it,
    which took ~0.3 s of a cold ``calib diagnose``'s two figures."""
    w, h = fig.get_size_inches()
    ax = fig.axes[0] if fig.axes else None
    gs = ax.get_subplotspec().get_gridspec() if ax is not None and ax.get_subplotspec() is not None else None
    nrows, ncols = gs.get_geometry() if gs is not None else (1, 1)
    aw = (w - left - right - wspace * (ncols - 1)) / ncols
    ah = (h - top - bottom - hspace * (nrows - 1)) / nrows
    fig.subplots_adjust(left=left / w, right=1.0 - right / w, top=1.0 - top / h, bottom=bottom / h,
                        wspace=wspace / aw if ncols > 1 else 0.2, hspace=hspace / ah if nrows > 1 else 0.2)


class InViewLocator(ticker.Locator):
    """The locations of ``inner`` that the axis draws: those inside the view interval, with the tolerance
    matplotlib's ``Axis`` uses to choose the ticks it draws. Matplotlib makes a tick object (two marks, a grid line,
    two labels) for every location a locator returns, drawn or not, and a log locator returns whole decades beyond
    each end of the view; on the Allan deviation figure those were a quarter of its ticks. Autoscaling
    (``nonsingular``, ``view_limits``) is the inner locator's, so the axis limits do not change."""

    def __init__(self, inner: ticker.Locator):
        self.inner = inner

    def set_axis(self, axis):
        super().set_axis(axis)
        self.inner.set_axis(axis)

    def __call__(self):
        return self._in_view(np.asarray(self.inner(), dtype=float))

    def tick_values(self, vmin, vmax):
        return self.inner.tick_values(vmin, vmax)

    def nonsingular(self, v0, v1):
        return self.inner.nonsingular(v0, v1)

    def view_limits(self, vmin, vmax):
        return self.inner.view_limits(vmin, vmax)

    def _in_view(self, locs):
        if self.axis is None or not locs.size:
            return locs
        transform = self.axis.get_transform()
        lo, hi = sorted(transform.transform(self.axis.get_view_interval()))
        tol = (hi - lo) * 1e-10                    # matplotlib.transforms._interval_contains_close
        at = transform.transform(locs)
        return locs[(at >= lo - tol) & (at <= hi + tol)]


def in_view_ticks(ax) -> None:
    """Major and minor ticks of both axes of ``ax`` only where they are drawn (:class:`InViewLocator`); call it
    after the axis scales are set (setting a scale replaces the locators)."""
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_locator(InViewLocator(axis.get_major_locator()))
        axis.set_minor_locator(InViewLocator(axis.get_minor_locator()))


def plain_log_ticks(ax, which: str = "x") -> None:
    """A log axis labelled 1, 2, 5, 10, 20, 50 ... in plain numbers, minor ticks unlabelled. Matplotlib's default
    labels the minor ticks of an axis spanning less than a decade as ``2x10^0``, ``3x10^0`` ..., which overlap."""
    from matplotlib import ticker

    axis = ax.xaxis if which == "x" else ax.yaxis
    axis.set_major_locator(ticker.LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(ticker.FuncFormatter(lambda v, _pos: f"{v:g}"))
    axis.set_minor_locator(ticker.LogLocator(base=10.0, subs=tuple(range(2, 10))))
    axis.set_minor_formatter(ticker.NullFormatter())


def ordinal(n: int) -> str:
    """``1st``, ``2nd``, ``3rd``, ``4th``, ``11th``, ``22nd`` ..."""
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


def _drop_spent_layout_engine(fig) -> None:
    """After ``fig.tight_layout()`` the figure keeps a placeholder layout engine that does nothing, yet its
    presence makes ``savefig`` draw the whole figure once more, without output, before the real draw. The layout
    is already fixed, so the placeholder goes: one draw instead of two, the same pixels."""
    from matplotlib.layout_engine import PlaceHolderLayoutEngine

    if isinstance(fig.get_layout_engine(), PlaceHolderLayoutEngine):
        with plt.rc_context({"figure.autolayout": False, "figure.constrained_layout.use": False}):
            fig.set_layout_engine(None)   # (None with these rc settings: no engine at all)


def save(fig, path) -> Path:
    """Save ``fig`` to ``path`` (format from the suffix) deterministically and atomically; closes it.

    The figure is first looked at by :func:`inspect` (see :data:`CHECK_ENV`): :func:`render`, then
    :func:`calib.figures.output.write_rendered`."""
    path = Path(path)
    return write_rendered(path, *render(fig, path.suffix))


def render(fig, suffix: str = ".png"):
    """``(bytes, problems)``: what :func:`save` would write for ``fig`` in format ``suffix``, and what
    :func:`inspect` found (written by :func:`calib.figures.output.write_rendered`); closes the figure. In strict
    mode a figure with problems is not rendered (``None``): it will be refused."""
    suffix, mode = suffix.lower(), check_mode()
    problems = inspect(fig) if mode != "off" else []
    if problems and mode == "strict":
        plt.close(fig)
        return None, problems
    _drop_spent_layout_engine(fig)
    buf = io.BytesIO()
    try:
        with plt.rc_context(STYLE):
            fig.savefig(buf, format=suffix[1:], metadata=_META.get(suffix))
    finally:
        plt.close(fig)
    return buf.getvalue(), problems

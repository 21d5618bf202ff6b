"""Ticks only where they are drawn (calib.figures.style.in_view_ticks): a log axis asks its locator for whole decades
beyond the view and matplotlib makes a tick object for each; the wrapped locators return only the locations inside
the view, and the figure is the same file, byte for byte, with the same axis limits."""
from __future__ import annotations

import numpy as np

from calib.figures import diagnosis_plots, style


def _loglog(in_view: bool):
    fig, ax = style.plt.subplots(figsize=(4.0, 3.0))
    tau = np.logspace(-2.0, 1.5, 12)
    ax.loglog(tau, 50.0 / np.sqrt(tau), "o-", label="x")
    ax.fill_between(tau, 40.0 / np.sqrt(tau), 60.0 / np.sqrt(tau), alpha=0.15, label="95 % interval")
    ax.set_xlabel("tau [s]")
    ax.set_ylabel("Allan deviation")
    ax.set_title("accel", y=1.0)
    ax.legend()
    if in_view:
        style.in_view_ticks(ax)
    return fig, ax


def _locations(ax):
    return {name: (np.asarray(axis.get_majorticklocs()), np.asarray(axis.get_minorticklocs()),
                   tuple(sorted(axis.get_view_interval()))) for name, axis in (("x", ax.xaxis), ("y", ax.yaxis))}


def test_the_same_figure_from_the_ticks_inside_the_view_only():
    plain_fig, plain_ax = _loglog(False)
    fig, ax = _loglog(True)
    plain, problems_plain = style.render(plain_fig, ".png")
    drawn, problems = style.render(fig, ".png")
    assert drawn == plain and problems == problems_plain == []
    before, after = _locations(plain_ax), _locations(ax)
    for name in ("x", "y"):
        major0, minor0, view0 = before[name]
        major, minor, view = after[name]
        assert view == view0                                       # autoscaling is the inner locator's
        lo, hi = view
        outside = lambda v: (v < lo * (1 - 1e-9)) | (v > hi * (1 + 1e-9))    # noqa: E731
        assert outside(major0).any() and outside(minor0).any()     # the log locator does reach beyond the view
        assert not outside(major).any() and not outside(minor).any()
        inside = lambda v: np.sort(v[~outside(v)])                  # noqa: E731
        assert np.array_equal(major, inside(major0)) and np.array_equal(minor, inside(minor0))


def test_the_allan_figure_makes_no_tick_it_does_not_draw():
    tau = np.array([0.01, 0.02, 0.04, 0.08, 0.16, 0.32, 0.64, 1.28, 2.56, 5.12, 10.24, 20.48, 30.0])
    adev = np.outer(50.0 / np.sqrt(tau / 0.01), [1.0, 0.95, 1.05])
    panel = {"tau": tau, "adev": adev, "lo": 0.8 * adev, "hi": 1.25 * adev, "edf": np.full(tau.size, 10.0),
             "unit": "count s-1", "confidence": 0.95}
    fig = diagnosis_plots.allan([("accel", panel), ("gyro", {**panel, "adev": 100.0 * adev,
                                                              "lo": 80.0 * adev, "hi": 125.0 * adev})])
    data, problems = style.render(fig, ".png")
    assert data and problems == []
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            lo, hi = sorted(axis.get_view_interval())
            locs = np.concatenate([axis.get_majorticklocs(), axis.get_minorticklocs()])
            assert locs.size and np.all((locs >= lo * (1 - 1e-9)) & (locs <= hi * (1 + 1e-9)))
            # every tick object made was asked for by a location in the view
            assert len(axis.majorTicks) <= len(axis.get_majorticklocs()) + 1
            assert len(axis.minorTicks) <= len(axis.get_minorticklocs()) + 1

"""What :func:`calib.figures.style.save` writes: after ``fig.tight_layout()`` the figure is drawn once (not a
dry-run draw first), with the same bytes as a save that keeps matplotlib's spent layout engine, and the same bytes
run after run."""
from __future__ import annotations

import io

import numpy as np

from calib.figures import style

plt = style.plt


def _figure():
    """Two log-log panels with bands and legends (the kind of figure the diagnosis writes), laid out tight."""
    rng = np.random.default_rng(3)
    fig, axs = plt.subplots(1, 2, figsize=(8, 3), squeeze=False)
    tau = np.logspace(-2, 2, 13)
    for ax, name in zip(axs[0], ("accel", "gyro")):
        for a in range(3):
            y = 1e-3 * (1 + a) / np.sqrt(tau) * (1 + 0.1 * rng.standard_normal(tau.size))
            line, = ax.loglog(tau, y, "o-", ms=3, label="xyz"[a])
            ax.fill_between(tau, 0.8 * y, 1.2 * y, color=line.get_color(), alpha=0.15)
        ax.set_xlabel("tau [s]")
        ax.set_ylabel(f"{name} Allan deviation")
        ax.legend()
    fig.tight_layout()
    return fig


def _draws(fig) -> list:
    seen = []
    fig.canvas.mpl_connect("draw_event", lambda event: seen.append(event))
    return seen


def test_a_tight_figure_is_drawn_once(tmp_path):
    fig = _figure()
    draws = _draws(fig)
    style.save(fig, tmp_path / "f.png")
    assert len(draws) == 1

    fig = _figure()   # matplotlib's own savefig of the same figure: a dry-run draw, then the real one
    draws = _draws(fig)
    fig.savefig(io.BytesIO(), format="png")
    plt.close(fig)
    assert len(draws) == 2


def test_one_draw_gives_the_same_bytes_as_two(tmp_path):
    for ext in ("png", "svg", "pdf"):
        path = style.save(_figure(), tmp_path / f"one.{ext}")
        fig = _figure()   # the save as it was: the spent layout engine kept, savefig draws twice
        with plt.rc_context(style.STYLE):
            fig.savefig(tmp_path / f"two.{ext}", format=ext, metadata=style._META[f".{ext}"])
        plt.close(fig)
        assert path.read_bytes() == (tmp_path / f"two.{ext}").read_bytes(), ext
        assert style.save(_figure(), tmp_path / f"again.{ext}").read_bytes() == path.read_bytes(), ext


def test_a_live_layout_engine_is_kept(tmp_path):
    """A constrained layout is done at draw time: save leaves it in place (it is not a spent engine)."""
    fig, ax = plt.subplots(layout="constrained")
    ax.plot([1, 2, 3], [1, 4, 9], label="a")
    ax.plot([1, 2, 3], [2, 5, 7], label="b")
    ax.set_xlabel("x [s]")
    ax.set_ylabel("y [m]")
    ax.legend()
    engine = fig.get_layout_engine()
    style._drop_spent_layout_engine(fig)
    assert fig.get_layout_engine() is engine
    style.save(fig, tmp_path / "c.png")


def test_ordinal():
    from calib.figures.style import ordinal

    assert [ordinal(n) for n in (1, 2, 3, 4, 11, 12, 13, 21, 22, 23, 101, 111, 112)] == \
        ["1st", "2nd", "3rd", "4th", "11th", "12th", "13th", "21st", "22nd", "23rd", "101st", "111th", "112th"]


def test_fixed_margins_place_axes_in_inches():
    """The margins asked for in inches are the axes' distances from the figure's edges, panels apart by the gap."""
    from calib.figures import style

    fig, axs = style.plt.subplots(2, 3, figsize=(9, 6))
    style.fixed_margins(fig, left=0.9, right=0.2, top=0.5, bottom=1.1, wspace=0.7, hspace=0.4)
    w, h = fig.get_size_inches()
    p00, p01, p10 = axs[0, 0].get_position(), axs[0, 1].get_position(), axs[1, 0].get_position()
    assert abs(p00.x0 * w - 0.9) < 1e-9 and abs((1 - axs[0, 2].get_position().x1) * w - 0.2) < 1e-9
    assert abs((1 - p00.y1) * h - 0.5) < 1e-9 and abs(p10.y0 * h - 1.1) < 1e-9
    assert abs((p01.x0 - p00.x1) * w - 0.7) < 1e-9 and abs((p00.y0 - p10.y1) * h - 0.4) < 1e-9
    style.plt.close(fig)


def _residual_data(after_shift):
    import numpy as np

    n = 6
    window = np.repeat(np.arange(n), 3)
    axis = np.tile(np.arange(3), n)
    before = np.linspace(-2.0, 2.0, 3 * n)
    return {"sensor": np.zeros(3 * n, int), "row": np.zeros(3 * n, int), "axis": axis, "window": window,
            "before": before, "after": before + after_shift, "sigma": np.ones(3 * n),
            "labels": [f"P{k}" for k in range(n)], "kind": "vector", "sensors": ["accel"], "row_names": ["mean"],
            "title": None}


def test_residual_figure_draws_one_series_per_axis_when_nothing_was_selected():
    """With no term selected the residuals before and after are one set of numbers: one series per axis under an
    x/y/z legend, titled as the base model's; with terms selected, before and after per axis."""
    from calib.figures import diagnosis_plots, style

    fig = diagnosis_plots.residual(_residual_data(0.0))
    ax = fig.axes[0]
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["x", "y", "z"]
    assert "no term selected" in fig._suptitle.get_text()
    style.plt.close(fig)
    fig = diagnosis_plots.residual(_residual_data(-0.5))
    assert [t.get_text() for t in fig.axes[0].get_legend().get_texts()] == \
        ["x before", "x after", "y before", "y after", "z before", "z after"]
    style.plt.close(fig)


def test_plain_log_ticks_on_less_than_a_decade():
    """A log axis over less than a decade: plain labels at 2 and 5, no '2x10^0'-style minor labels to overlap."""
    from calib.figures import style

    fig, ax = style.plt.subplots()
    ax.plot([1.5, 8.0], [0.0, 1.0])
    ax.set_xscale("log")
    ax.set_xlim(1.5, 8.0)
    style.plain_log_ticks(ax, "x")
    fig.canvas.draw()
    lo, hi = ax.get_xlim()
    major = [t.get_text() for t in ax.get_xticklabels() if lo <= t.get_position()[0] <= hi]
    minor = [t.get_text() for t in ax.get_xticklabels(minor=True) if t.get_text()]
    assert major == ["2", "5"] and minor == []
    style.plt.close(fig)


def test_residual_figure_rings_where_the_unexplained_misfit_sits():
    """An unexplained misfit's observations are ringed in the panel of their sensor and row, under the name the
    report gives it; panels without one get no such series."""
    import numpy as np

    from calib.figures import diagnosis_plots, style

    d = _residual_data(-0.5)
    d["sensor"] = np.r_[np.zeros(9, int), np.ones(9, int)]
    d["sensors"] = ["accel", "gyro"]
    d["unexplained"] = [("gyro x: rotation windows", np.array([9, 12]))]
    fig = diagnosis_plots.residual(d)
    acc, gyr = fig.axes
    ringed = [ln for ln in gyr.get_lines() if ln.get_label() == "unexplained misfit: gyro x: rotation windows"]
    assert len(ringed) == 1 and len(ringed[0].get_xdata()) == 2
    assert not [ln for ln in acc.get_lines() if str(ln.get_label()).startswith("unexplained")]
    assert "unexplained misfit: gyro x: rotation windows" in [t.get_text() for t in gyr.get_legend().get_texts()]
    style.plt.close(fig)


def test_residual_figure_of_the_norm_model_draws_one_series():
    """The norm model has one residual per segment: one series (before and after), named 'norm', no x/y/z."""
    import numpy as np

    from calib.figures import diagnosis_plots, style

    d = _residual_data(-0.5)
    keep = d["axis"] == 0
    d = {k: (v[keep] if isinstance(v, np.ndarray) else v) for k, v in d.items()}
    d["kind"] = "norm"
    fig = diagnosis_plots.residual(d)
    assert [t.get_text() for t in fig.axes[0].get_legend().get_texts()] == ["norm before", "norm after"]
    style.plt.close(fig)

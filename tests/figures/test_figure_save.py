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

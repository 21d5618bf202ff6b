"""The figure inspection that every saved figure passes (strict in CI): it finds what a reader would miss."""
from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from calib.figures import style  # noqa: E402


def _good():
    fig, ax = plt.subplots()
    ax.plot([1, 2, 3], [1, 4, 9], label="a")
    ax.plot([1, 2, 3], [2, 5, 7], label="b")
    ax.set_xlabel("x [s]")
    ax.set_ylabel("y [m]")
    ax.legend()
    return fig


def test_a_readable_figure_passes():
    fig = _good()
    assert style.inspect(fig) == []
    plt.close(fig)


def test_each_defect_is_found():
    fig, axs = plt.subplots(2, 2)
    axs[0, 0].plot([1, 2], [1, 2], label="a")
    axs[0, 0].plot([1, 2], [2, 1], label="b")           # two labelled series, no legend anywhere
    axs[0, 0].set_xlabel("x")                            # no y label
    axs[0, 1].set_xlabel("x")
    axs[0, 1].set_ylabel("y")                            # labelled but empty
    axs[1, 0].plot([1, 2, 3], [200, 205, 210])
    axs[1, 0].set_yscale("log")                          # log over 200..210
    axs[1, 0].set_xlabel("x")
    axs[1, 0].set_ylabel("y")
    for k in range(3):
        axs[1, 1].plot([1, 2], [k, k + 1])               # three unlabelled series
    axs[1, 1].set_xlabel("x")
    axs[1, 1].set_ylabel("y")
    found = " | ".join(style.inspect(fig))
    plt.close(fig)
    assert "panel 1 has no y label" in found
    assert "panel 1 draws 2 labelled series without a legend" in found
    assert "panel 2 is empty" in found
    assert "panel 3: log y axis" in found
    assert "panel 4 draws 3 series, none labelled" in found


def test_switched_off_panel_and_shared_labels_are_fine():
    fig, axs = plt.subplots(2, 2, sharex=True, sharey=True)
    for ax in axs.flat[:3]:
        ax.plot(np.arange(5), np.arange(5) ** 2)
    axs[1, 0].set_xlabel("x")
    axs[0, 0].set_ylabel("y")
    axs[1, 1].axis("off")
    assert style.inspect(fig) == []
    plt.close(fig)


def test_strict_mode_refuses_and_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv(style.CHECK_ENV, "strict")
    fig, ax = plt.subplots()
    ax.set_xlabel("x")
    with pytest.raises(style.FigureCheckError, match="empty"):
        style.save(fig, tmp_path / "f.png")
    assert list(tmp_path.iterdir()) == []
    style.save(_good(), tmp_path / "g.png")
    assert (tmp_path / "g.png").stat().st_size > 0

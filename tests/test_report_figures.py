"""bench.report's figures: a norms figure tells every design apart, keeps its key off the data,
labels both panels' axes and names the floor that clips its log axes."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.colors as mcolors  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from bench.report import NORM_FLOOR, _FigureJob, _norms_figure, _states_figure  # noqa: E402


def _job(n_designs: int, *, exact_zero: bool) -> _FigureJob:
    t = np.linspace(0.0, 20.0, 201)
    data = []
    for k in range(n_designs):
        nx = 5.0 * np.exp(-(0.5 + 0.1 * k) * t)
        ne = 3.0 * np.exp(-(1.0 + 0.1 * k) * t)
        if exact_zero and k == 0:
            ne = np.where(t > 2.0, 0.0, ne)  # an estimator whose error is exactly 0 (the EKF on a linear output)
        data.append((f"design_{k}", t, nx, ne))
    return _FigureJob("norms", "p__norms", "caption", "p", tuple(data))


def _design_lines(ax):
    return [ln for ln in ax.get_lines() if ln.get_label().startswith("design_")]


def test_fifteen_designs_each_have_their_own_colour_and_line_style():
    fig, _ = _norms_figure(_job(15, exact_zero=False))
    try:
        state, error = fig.axes[:2]
        for ax in (state, error):
            lines = _design_lines(ax)
            assert len(lines) == 15
            colours = [mcolors.to_hex(ln.get_color()) for ln in lines]
            assert len(set(colours)) == 15, colours  # no colour reused
            styles = {(c, str(ln.get_linestyle()), str(ln.get_dashes() if hasattr(ln, "get_dashes") else ""))
                      for c, ln in zip(colours, lines)}
            assert len(styles) == 15
            assert len({str(ln.get_linestyle()) for ln in lines}) >= 4  # the styles vary too (greyscale print)
        # each design drawn alike in both panels
        assert [mcolors.to_hex(ln.get_color()) for ln in _design_lines(state)] == \
               [mcolors.to_hex(ln.get_color()) for ln in _design_lines(error)]
    finally:
        plt.close(fig)


def test_key_is_outside_the_data_panels_and_axes_are_labelled():
    fig, _ = _norms_figure(_job(13, exact_zero=False))
    try:
        state, error = fig.axes[:2]
        assert state.get_legend() is None and error.get_legend() is None  # no legend over the curves
        keys = [ax for ax in fig.axes if ax.get_legend() is not None]
        assert len(keys) == 1
        key = keys[0]
        assert not key.axison and not key.get_lines()  # a panel of its own, no data in it
        labels = [tx.get_text() for tx in key.get_legend().get_texts()]
        assert labels[:13] == [f"design_{k}" for k in range(13)]
        # the key's panel lies right of both data panels
        assert key.get_position().x0 >= max(state.get_position().x1, error.get_position().x1)
        for ax in (state, error):
            assert ax.get_xlabel() and ax.get_ylabel()
            assert ax.get_yscale() == "log"
        assert "x" in state.get_ylabel() and "e" in error.get_ylabel()
    finally:
        plt.close(fig)


def test_a_clipped_norm_draws_and_names_the_floor():
    fig, _ = _norms_figure(_job(3, exact_zero=True))
    try:
        error = fig.axes[1]
        floors = [ln for ln in error.get_lines() if "floor" in ln.get_label()]
        assert len(floors) == 1
        assert np.allclose(floors[0].get_ydata(), NORM_FLOOR)
        assert f"{NORM_FLOOR:.0e}" in floors[0].get_label()
        key = next(ax for ax in fig.axes if ax.get_legend() is not None)
        assert any("floor" in tx.get_text() for tx in key.get_legend().get_texts())
        # the exact zero is drawn on the floor, not dropped
        ekf = _design_lines(error)[0]
        assert np.min(ekf.get_ydata()) == NORM_FLOOR
    finally:
        plt.close(fig)
    fig, _ = _norms_figure(_job(3, exact_zero=False))
    try:
        assert not any("floor" in ln.get_label() for ax in fig.axes[:2] for ln in ax.get_lines())
    finally:
        plt.close(fig)


def test_states_figure_labels_its_axes_with_the_units():
    t = np.linspace(0, 5, 51)
    x = np.vstack([np.exp(-t), -np.exp(-2 * t)])
    names = ("theta [rad]", "x2")  # a state with its unit, one without (no state_names)
    fig, _ = _states_figure(_FigureJob("states", "p__d", "caption", "title", (t, x, 0.9 * x, 5.0, names)))
    try:
        assert len(fig.axes) == 4
        for ax in fig.axes:
            assert ax.get_xlabel() == "t [s]" and ax.get_ylabel()
        top, bottom = fig.axes[0], fig.axes[2]  # x1's panels: state and error
        assert top.get_title() == "x1: theta [rad]" and top.get_ylabel().endswith("[rad]")
        assert bottom.get_ylabel().endswith("[rad]")
        assert fig.axes[1].get_title() == "x2 and its estimate" and "[" not in fig.axes[1].get_ylabel()
    finally:
        plt.close(fig)

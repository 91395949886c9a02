"""The PNG's panels: ATE bars with the spread, error against 3-sigma bands per setting, best and worst on top."""

from __future__ import annotations

import numpy as np
from matplotlib.colors import to_rgb

from airimu.experiments.pgo import PgoRow
from airimu.viz import colors
from airimu.viz.figures import figure, plot_run

SETTINGS = ("raw IMU + fixed cov", "AirIMU + fixed cov", "raw IMU + learned cov", "AirIMU + learned cov")
ATE = {1.0: (0.12, 0.10, 0.14, 0.09), 0.1: (13.2, 2.3, 14.2, 2.29)}


def _run():
    rows = [PgoRow(s, rate, "seq", ate[i], 0.01 * (i + 1)) for rate, ate in ATE.items() for i, s in enumerate(SETTINGS)]
    t = np.linspace(0.0, 10.0, 101)
    truth = (t, np.column_stack([np.cos(t), np.sin(t), np.zeros_like(t)]))
    fused = {}
    for i, name in enumerate(SETTINGS):
        offset = np.where(t < 5.0, 0.1, 0.5) if i == 0 else np.full_like(t, 0.1)  # the first leaves its band
        cov = np.repeat(np.eye(3)[None] * 0.01, len(t), axis=0)  # 3 sigma = 0.3 m
        fused[name] = (t, truth[1] + offset[:, None] * [1.0, 0.0, 0.0], cov)
    return rows, fused, truth, (t[::10], truth[1][::10])


def _rgb(color):
    return tuple(c / 255 for c in color)


def test_panels_show_ate_bars_bands_and_best_and_worst():
    rows, fused, truth, gps = _run()
    fig = figure("seq", rows, fused, truth, gps)
    axes = {ax.get_title(loc="left") or ax.get_title(): ax for ax in fig.axes}
    bars = next(ax for title, ax in axes.items() if title.startswith("ATE per setting"))
    heights = [p.get_height() for p in bars.patches]
    np.testing.assert_allclose(heights, [*ATE[1.0], *ATE[0.1]])  # first rate, then the second
    assert [to_rgb(p.get_facecolor()) for p in bars.patches[:4]] == [_rgb(colors.setting_color(s)) for s in SETTINGS]
    assert bars.get_yscale() == "log"  # 0.09 m to 14 m
    assert len(bars.containers) == 4  # two bar groups, each with its error bars (the spread)
    # one small panel per setting, coloured, saying how often the error stays inside its 3-sigma band
    assert axes["raw IMU + fixed cov  (50% inside 3σ)"] is not None
    assert axes["AirIMU + learned cov  (100% inside 3σ)"] is not None
    band = axes["AirIMU + learned cov  (100% inside 3σ)"]
    np.testing.assert_allclose(band.lines[0].get_ydata(), 0.3)  # the bound: 3 sqrt(0.01)
    assert to_rgb(band.lines[1].get_color()) == _rgb(colors.setting_color("AirIMU + learned cov"))
    top = next(ax for title, ax in axes.items() if title.startswith("top view"))
    labels = top.get_legend_handles_labels()[1]
    assert "best: AirIMU + learned cov (0.09 m)" in labels and "worst: raw IMU + learned cov (0.14 m)" in labels
    assert "ground truth" in labels and "GPS fixes (fused)" in labels
    assert not any(label.startswith("AirIMU + fixed") for label in labels)  # only the best and the worst


def test_a_single_run_without_truth_or_rows_gets_bounds_and_the_track(tmp_path):
    _, fused, _, gps = _run()
    one = {"fused": fused["AirIMU + learned cov"]}
    path = plot_run(tmp_path / "fused.png", "log", [], one, None, gps)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    fig = figure("log", [], one, None, gps)
    titles = [ax.get_title(loc="left") or ax.get_title() for ax in fig.axes]
    assert not any(t.startswith("ATE") for t in titles) and "fused" in titles
    top = next(ax for ax in fig.axes if ax.get_title().startswith("top view"))
    assert top.get_legend_handles_labels()[1] == ["GPS fixes (fused)", "fused"]

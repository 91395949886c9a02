"""The PNG of a fusion run (matplotlib, Agg): what a reader of a report wants at a glance.

Three panels, in the colours of the Rerun recording (``airimu.viz.colors``):

- ATE per setting and GPS rate: bars with the spread (mean +- std over the GPS seeds), log scale when the values
  span more than a decade;
- position error over time, a small panel per setting, with its 3-sigma band (the longest half-axis of the 3-sigma
  ellipsoid of the marginal, as in the recording) and the share of keyframes inside it; first GPS rate, seed 0;
- a top-down trajectory (x-y, m): ground truth against the best and the worst setting of that rate, and the fixes.

Without ablation rows (``airimu fuse``) the bars are left out; without ground truth the error panel shows the
bounds alone and the trajectory panel every fused track.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np

from airimu.viz import colors

SIGMA_SCALE = 3.0  # the bands, in standard deviations (as airimu.viz.recording.SIGMA_SCALE)
DPI = 110


def plot(result, path: str | Path) -> Path:
    """A PNG of one sequence's result (``airimu.viz.results.SequenceResult``), written atomically."""
    from airimu.viz.results import marginal_track

    seq = result.sequence
    fused = {name: marginal_track(solution) for name, (solution, _) in result.examples.items()}
    gps = next(iter(result.examples.values()))[1]
    truth = (seq.t, seq.gt.pos) if seq.gt is not None else None
    return plot_run(path, seq.name, result.rows, fused, truth, (gps.t, gps.pos), result.outages)


def plot_run(
    path: str | Path,
    title: str,
    rows: list,
    fused: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray | None]],
    truth: tuple[np.ndarray, np.ndarray] | None,
    gps: tuple[np.ndarray, np.ndarray] | None,
    outages: tuple = (),
) -> Path:
    """Write ``figure(...)`` as a PNG, atomically."""
    from matplotlib import pyplot as plt

    from airimu_core.io import atomic_file

    fig = figure(title, rows, fused, truth, gps, outages)
    with atomic_file(path, "wb") as f:
        fig.savefig(f, format="png", dpi=DPI)
    plt.close(fig)
    return Path(path)


def figure(title: str, rows: list, fused: dict, truth, gps, outages: tuple = ()):
    """The matplotlib figure. ``rows``: ``airimu.experiments.pgo.PgoRow`` (setting, gps_hz, ate_mean_m, ate_std_m);
    ``fused``: setting -> (t (K,) s, pos (K, 3) m, pos_cov (K, 3, 3) m^2 or None) at the first rate;
    ``truth``, ``gps``: (t (N,) s, pos (N, 3) m) or None; ``outages``: (first, last) s of each GPS outage, shaded
    grey in the error panels and drawn thick on the fused track of the top view."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    palette = colors.setting_colors(list(fused))
    rate = rows[0].gps_hz if rows else None
    fig = plt.figure(figsize=(15, 8.5) if rows else (14, 6.5), layout="constrained")
    grid = fig.add_gridspec(2, 2, width_ratios=[1, 1.25]) if rows else fig.add_gridspec(1, 2, width_ratios=[1, 1.4])
    top_down = fig.add_subplot(grid[:, 0])
    if rows:
        _ate_bars(fig.add_subplot(grid[0, 1]), rows, palette)
    _errors(fig, grid[1, 1] if rows else grid[0, 1], fused, truth, palette, rate, outages)
    _top_down(top_down, rows, fused, truth, gps, palette, rate, outages)
    fig.suptitle(f"{title}: IMU + GPS pose graph", fontsize=13)
    return fig


def _rgb(color) -> tuple[float, float, float]:
    return tuple(c / 255 for c in color)


def _ate_bars(ax, rows: list, palette: dict) -> None:
    settings = list(dict.fromkeys(r.setting for r in rows))
    rates = sorted({r.gps_hz for r in rows}, reverse=True)
    cells = {(r.setting, r.gps_hz): r for r in rows}
    width = 0.8 / len(rates)
    hatches = ["", "//", "..", "xx"]
    for j, rate in enumerate(rates):
        x = np.arange(len(settings)) + (j - (len(rates) - 1) / 2) * width
        mean = [cells[(s, rate)].ate_mean_m if (s, rate) in cells else np.nan for s in settings]
        std = [cells[(s, rate)].ate_std_m if (s, rate) in cells else np.nan for s in settings]
        face = [_rgb(palette.get(s, colors.setting_color(s))) for s in settings]
        style = {"hatch": hatches[j % len(hatches)], "alpha": 1.0 if j == 0 else 0.7, "label": f"GPS {rate:g} Hz"}
        bars = ax.bar(x, mean, width * 0.95, yerr=std, capsize=3, color=face, edgecolor="black", lw=0.6, **style)
        ax.bar_label(bars, labels=[f"{m:.3g}" for m in mean], fontsize=7, padding=2)
    values = [r.ate_mean_m for r in rows if r.ate_mean_m > 0]
    if values and max(values) / min(values) > 10:
        ax.set_yscale("log")
    ax.set_xticks(np.arange(len(settings)), [textwrap.fill(s, 14) for s in settings], fontsize=8)
    ax.set(ylabel="ATE (m)", title="ATE per setting and GPS rate (mean ± std over GPS seeds)")
    ax.margins(y=0.15)
    ax.legend(fontsize=8, loc="upper left", frameon=False)
    ax.grid(axis="y", alpha=0.3)


def _errors(fig, cell, fused: dict, truth, palette: dict, rate, outages=()) -> None:
    """One small panel per setting (shared axes): its error and its 3-sigma band, and how often the error stays
    inside the band."""
    names = list(fused)
    ncols = 1 if len(names) == 1 else 2
    nrows = -(-len(names) // ncols)
    axes = cell.subgridspec(nrows, ncols).subplots(sharex=True, sharey=True, squeeze=False).ravel()
    at = f" (GPS {rate:g} Hz, seed 0)" if rate else ""
    what = "position error (m) against its 3σ band" if truth is not None else "3σ position bound (m)"
    axes[0].annotate(f"{what}{at}", (0, 1.25), xycoords="axes fraction", fontsize=11)
    for ax, name in zip(axes, names, strict=False):  # a spare panel stays empty
        t, pos, cov = fused[name]
        color = _rgb(palette[name])
        label = ""
        if cov is not None:
            bound = SIGMA_SCALE * np.sqrt(np.clip(np.linalg.eigvalsh(cov)[:, -1], 0.0, None))
            ax.fill_between(t, 0.0, bound, color=color, alpha=0.18, linewidth=0)
            ax.plot(t, bound, color=color, lw=0.8, ls="--")
        if truth is not None:
            err = np.linalg.norm(
                pos - np.column_stack([np.interp(t, truth[0], truth[1][:, i]) for i in range(3)]), axis=1
            )
            ax.plot(t, err, color=color, lw=1.2)
            if cov is not None:
                label = f"  ({np.mean(err <= bound):.0%} inside 3σ)"
        for k, (first, last) in enumerate(outages):
            ax.axvspan(first, last, color="0.6", alpha=0.3, lw=0, label="GPS outage" if k == 0 else None)
        if outages:
            ax.legend(fontsize=7, loc="upper left", frameon=False)
        ax.set_title(f"{name}{label}", fontsize=9, color=color, loc="left")
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    for ax in axes[len(names) :]:
        ax.set_visible(False)
    for ax in axes[-ncols:]:
        ax.set_xlabel("time (s)")


def _top_down(ax, rows: list, fused: dict, truth, gps, palette: dict, rate, outages=()) -> None:
    shown = list(fused)
    ranked = sorted((r for r in rows if r.gps_hz == rate and r.setting in fused), key=lambda r: r.ate_mean_m)
    labels = {name: name for name in fused}
    if len(ranked) >= 2:
        best, worst = ranked[0], ranked[-1]
        shown = [best.setting, worst.setting]
        labels = {
            best.setting: f"best: {best.setting} ({best.ate_mean_m:.3g} m)",
            worst.setting: f"worst: {worst.setting} ({worst.ate_mean_m:.3g} m)",
        }
    if gps is not None:
        ax.plot(gps[1][:, 0], gps[1][:, 1], "o", ms=3.5, color=_rgb(colors.GPS), label="GPS fixes (fused)", zorder=1)
    if truth is not None:
        ax.plot(truth[1][:, 0], truth[1][:, 1], color=_rgb(colors.GROUND_TRUTH), lw=2.2, label="ground truth", zorder=2)
        ax.plot(*truth[1][0, :2], "k^", ms=8, label="start", zorder=5)
    for name in shown:
        t, pos = fused[name][0], fused[name][1]
        ax.plot(pos[:, 0], pos[:, 1], color=_rgb(palette[name]), lw=1.3, label=labels[name], zorder=3)
        for k, (first, last) in enumerate(outages):
            during = (t >= first) & (t <= last)
            label = "GPS outage" if k == 0 and name == shown[0] else None
            ax.plot(pos[during, 0], pos[during, 1], color="0.35", lw=5, alpha=0.35, label=label, zorder=2.5)
    at = f" (GPS {rate:g} Hz, seed 0)" if rate else ""
    ax.set(xlabel="x (m)", ylabel="y (m)", title=f"top view{at}", aspect="equal")
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=2, frameon=False)
    ax.grid(alpha=0.3)

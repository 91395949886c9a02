"""Rerun recordings of a fusion run and of a training run (the only module that imports rerun).

Entity layout of a fusion recording, one time line ``time`` in seconds (IMU clock), world frame, m:

- ``world/ground_truth``: ``LineStrips3D`` (static, near black, labelled); ``world/ground_truth/now``: the true
  position at every keyframe (a moving marker);
- ``world/gps``: every fused fix (``Points3D``, static, magenta); ``world/gps/fix``: each fix at its time (marks
  on the time line, the latest fix drawn larger);
- ``world/fused/<setting>``: the solved trajectory (static, the setting's colour, ``airimu.viz.colors``);
  ``.../now``: the keyframe at the time cursor; ``.../covariance``: ``Ellipsoids3D`` of the marginal position
  covariance at the keyframe (3-sigma), per keyframe on the time line;
- ``world/dead_reckoning/<track>``: raw and AirIMU dead reckoning, kept out of the default 3-D view (they drift
  kilometres and would set its camera) and shown in their own tab;
- ``error/position/<setting>`` m: |fused - truth| at the keyframes; ``error/sigma3/<setting>`` m: the longest
  half-axis of the 3-sigma ellipsoid (3 sqrt of the largest eigenvalue of the marginal), the bound to check
  against; ``error/dead_reckoning/<track>`` m: dead-reckoning drift;
- ``imu/gyro`` rad/s, ``imu/acc`` m/s^2 (raw); ``correction/gyro``, ``correction/acc``; ``sigma/gyro``
  rad/s/sqrt(Hz), ``sigma/acc`` m/s^2/sqrt(Hz) (square roots of the learned densities): three columns x, y, z.

Every series is named and coloured with a static ``SeriesLines``. Whole series go in with ``rr.send_columns``;
constants are ``static``. The blueprint: the 3-D view (dead reckoning excluded, ellipsoids of the headline setting
visible, the others hidden, in the blueprint panel) beside tabs of plots split by unit; the time panel open, the
blueprint panel collapsed (its narrow tree cut the names; each view names itself).
``airimu view out.rrd`` opens the viewer.

A training recording (``write_training_recording``, ``<run>/training.rrd``, rewritten after every epoch), time line
``epoch``: ``loss`` (train and validation; ``loss/best`` marks the epoch ``best.pt`` holds), ``val/roe_deg``,
``val/rpe_rmse_m``, ``lr``, ``seconds``; ``loss/early_stop`` marks the last epoch of a run that stopped early;
``description``, the run in a sentence. A fusion recording's ``description`` names it and scores each setting (ATE
against the ground truth), each track carries its name at a different stretch of it (``.../label``: at the tracks'
common end the names overlapped), and the time panel opens paused with the whole run selected.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from airimu.viz import colors
from airimu_core.rotations import matrix_to_quat_wxyz
from learned_imu.training.train import EpochLog, stopped_early

TIMELINE = "time"
SIGMA_SCALE = 3.0  # ellipsoid half-sizes and error bounds in standard deviations
LEGEND_HEADROOM = 0.6  # fraction of a plot's data range left free above the curves for the legend
VIEW_BACKGROUND = (250, 250, 250)  # light, so that the dark ground truth reads as in the PNG
LINE = rr.Radius.ui_points(1.2)
TRUTH_LINE = rr.Radius.ui_points(2.5)  # drawn under the thinner fused lines
MARKER = rr.Radius.ui_points(5.0)
OUTAGE_LINE = rr.Radius.ui_points(7.0)  # a GPS outage's stretch, under the tracks


@dataclass(frozen=True, eq=False)
class Track:
    """A named trajectory to draw: ``t`` (K,) s, ``pos`` (K, 3) m, world frame; optional ``pos_cov`` (K, 3, 3)."""

    name: str
    t: np.ndarray
    pos: np.ndarray
    pos_cov: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class ImuSeries:
    """Per-sample series: ``t`` (N,) s; raw ``gyro``/``acc``; ``d_gyro``/``d_acc`` corrections; ``gyro_cov``/
    ``acc_cov`` learned densities (rad^2/s, m^2/s^3). All (N, 3), IMU frame."""

    t: np.ndarray
    gyro: np.ndarray
    acc: np.ndarray
    d_gyro: np.ndarray | None = None
    d_acc: np.ndarray | None = None
    gyro_cov: np.ndarray | None = None
    acc_cov: np.ndarray | None = None


@dataclass
class _Plot:
    """One time-series view: its title (with the unit), entities, and the y range of their data."""

    title: str
    entities: list[str]
    lo: float = np.inf
    hi: float = -np.inf

    def include(self, values: np.ndarray) -> None:
        finite = values[np.isfinite(values)]
        if finite.size:
            self.lo, self.hi = min(self.lo, float(finite.min())), max(self.hi, float(finite.max()))


@dataclass
class _Plots:
    error: list[_Plot] = field(default_factory=list)  # all settings, then one per setting with its bound
    drift: list[_Plot] = field(default_factory=list)
    sensors: dict[str, list[_Plot]] = field(default_factory=dict)  # "gyro" / "acc" -> raw, correction, sigma


def write_recording(
    path: str | Path,
    fused: list[Track],
    truth: Track | None = None,
    dead_reckoning: list[Track] = (),
    gps: tuple[np.ndarray, np.ndarray] | None = None,
    imu: ImuSeries | None = None,
    application: str = "airimu",
    outages: tuple = (),
) -> Path:
    """Write an ``.rrd`` (atomically). ``fused``: solved trajectories (with ``pos_cov`` for ellipsoids and
    bounds); ``truth`` scores them; ``dead_reckoning``: raw/AirIMU integration; ``gps`` = (t (M,), pos (M, 3));
    ``outages``: (first, last) s of each GPS outage (``_log_outages``)."""
    path = Path(path)
    with _saved(path, rr.RecordingStream(application)) as rec:
        plots = _Plots()
        names = [t.name for t in fused]
        palette = colors.setting_colors(names + [t.name for t in dead_reckoning])
        _log_world(rec, fused, truth, dead_reckoning, gps, palette)
        _log_errors(rec, fused, truth, dead_reckoning, palette, plots)
        if outages and fused:
            _log_outages(rec, fused, outages, plots)
        if imu is not None:
            _log_imu(rec, imu, plots)
        scene = truth.pos if truth is not None else (fused[0].pos if fused else np.zeros((1, 3)))
        rec.log(
            "description",
            rr.TextDocument(
                _description(application, fused, truth, dead_reckoning, gps), media_type=rr.MediaType.MARKDOWN
            ),
            static=True,
        )
        span = _time_span(fused, gps)
        rec.send_blueprint(_blueprint(fused, colors.headline(names), plots, _eye(scene), span), make_active=True)
    return path


def _description(application: str, fused, truth, dead_reckoning, gps) -> str:
    """The recording's text panel: what it is, its data and every setting with its ATE against the ground truth."""
    lines = [f"**{application}**", ""]
    if fused:
        t = fused[0].t
        lines.append(
            f"{len(t)} keyframes over {float(t[-1] - t[0]):.1f} s; ground truth: {'yes' if truth else 'no'}; "
            f"GPS fixes fused: {0 if gps is None else len(gps[0])}."
        )
    lines += ["", "| setting | ATE vs ground truth (m) |", "|---|---|"]
    for track in fused:
        error = None if truth is None else np.sqrt(np.mean(np.sum((track.pos - _at(truth, track.t)) ** 2, axis=1)))
        ate = "-" if error is None else f"{float(error):.3f}"
        lines.append(f"| {track.name} | {ate} |")
    if dead_reckoning:
        lines += ["", "Dead reckoning (own tab): " + ", ".join(t.name for t in dead_reckoning) + "."]
    lines += [
        "",
        "3-D view: each setting's track carries its name (at a different stretch of each track); the "
        "ellipsoids (3-sigma marginal position covariance at the time cursor) are shown for the headline "
        "setting, the others' in the blueprint panel (the icon at the top right opens it). Plots: position "
        "error against its 3-sigma bound per setting, and the IMU.",
    ]
    return "\n".join(lines)


def _time_span(fused, gps) -> tuple[int, int] | None:
    """(first, last) time of the recording, ns, for the time panel's selection: it opens on the whole run."""
    times = [t.t for t in fused] + ([gps[0]] if gps is not None else [])
    if not times or not any(len(t) for t in times):
        return None
    first, last = min(float(t[0]) for t in times if len(t)), max(float(t[-1]) for t in times if len(t))
    return int(round(first * 1e9)), int(round(last * 1e9))


def _log_world(rec, fused, truth, dead_reckoning, gps, palette) -> None:
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    if truth is not None:
        _log_track(rec, "world/ground_truth", truth, colors.GROUND_TRUTH, show_label=True, radius=TRUTH_LINE)
        if fused:
            t = fused[0].t
            _send(rec, "world/ground_truth/now", t, rr.Points3D.columns(positions=_at(truth, t)))
            rec.log(
                "world/ground_truth/now", rr.Points3D.from_fields(colors=colors.GROUND_TRUTH, radii=MARKER), static=True
            )
    if gps is not None:
        t, pos = gps
        rec.log("world/gps", rr.Points3D(pos, colors=colors.GPS, radii=rr.Radius.ui_points(3.0)), static=True)
        _send(rec, "world/gps/fix", t, rr.Points3D.columns(positions=pos))
        fix = rr.Points3D.from_fields(
            colors=colors.GPS, radii=rr.Radius.ui_points(7.0), labels="GPS fix", show_labels=False
        )
        rec.log("world/gps/fix", fix, static=True)
    for track in fused:
        entity, color = f"world/fused/{_slug(track.name)}", palette[track.name]
        _log_track(rec, entity, track, color, show_label=False)
        _send(rec, f"{entity}/now", track.t, rr.Points3D.columns(positions=track.pos))
        rec.log(
            f"{entity}/now",
            rr.Points3D.from_fields(colors=color, radii=MARKER, labels=track.name, show_labels=False),
            static=True,
        )
        at = _label_point(track, fused.index(track), len(fused))  # a name, not only a colour
        rec.log(
            f"{entity}/label",
            rr.Points3D(at, colors=color, radii=MARKER, labels=track.name, show_labels=True),
            static=True,
        )
        if track.pos_cov is not None:
            _send_ellipsoids(rec, f"{entity}/covariance", track, color)
    for track in dead_reckoning:
        _log_track(rec, f"world/dead_reckoning/{_slug(track.name)}", track, palette[track.name], show_label=True)


def _label_point(track: Track, i: int, n: int) -> np.ndarray:
    """(1, 3) where setting ``i`` of ``n`` carries its name: a different stretch of its track for each (the tracks
    end close together, where their labels overlapped), from the middle on, away from the ground truth's label."""
    k = int(round((len(track.pos) - 1) * (0.5 + 0.5 * (i + 1) / (n + 1))))
    return track.pos[k : k + 1]


def _log_track(rec, entity: str, track: Track, color, show_label: bool, radius=LINE) -> None:
    strip = rr.LineStrips3D([track.pos], colors=color, radii=radius, labels=track.name, show_labels=show_label)
    rec.log(entity, strip, static=True)


def _log_errors(rec, fused, truth, dead_reckoning, palette, plots: _Plots) -> None:
    """Position error of every setting against its 3-sigma bound, and the dead-reckoning drift."""
    if truth is not None and fused:
        overview = _Plot("position error, all settings (m)", [])
        plots.error.append(overview)
    for track in fused:
        slug, color = _slug(track.name), palette[track.name]
        mine = _Plot(f"{track.name} (m)", [])
        if truth is not None:
            error = np.linalg.norm(track.pos - _at(truth, track.t), axis=1)
            _send_series(rec, f"error/position/{slug}", track.t, error[:, None], [track.name], [color])
            for plot in (overview, mine):
                plot.entities.append(f"error/position/{slug}")
                plot.include(error)
        if track.pos_cov is not None:
            bound = SIGMA_SCALE * np.sqrt(np.clip(np.linalg.eigvalsh(track.pos_cov)[:, -1], 0.0, None))
            _send_series(
                rec,
                f"error/sigma3/{slug}",
                track.t,
                bound[:, None],
                [f"{track.name}: 3σ"],
                [colors.lighter(color, 0.55)],
            )
            mine.entities.append(f"error/sigma3/{slug}")
            mine.include(bound)
        if mine.entities:
            plots.error.append(mine)
    per_setting = [p for p in plots.error if p.title != "position error, all settings (m)"]
    if per_setting:  # comparable plots share one y range
        lo, hi = min(p.lo for p in per_setting), max(p.hi for p in per_setting)
        for plot in per_setting:
            plot.lo, plot.hi = lo, hi
    if truth is not None and dead_reckoning:
        drift = _Plot("dead-reckoning drift from ground truth (m)", [])
        for track in dead_reckoning:
            error = np.linalg.norm(track.pos - _at(truth, track.t), axis=1)
            entity = f"error/dead_reckoning/{_slug(track.name)}"
            _send_series(
                rec, entity, track.t, error[:, None], [f"{track.name} (dead reckoning)"], [palette[track.name]]
            )
            drift.entities.append(entity)
            drift.include(error)
        plots.drift.append(drift)


def _log_outages(rec, fused, outages, plots: _Plots) -> None:
    """GPS outages: each one's stretch of every fused track as a thick grey band in the 3-D view
    (``world/gps_outage/<k>``), and a series ``error/gps_outage`` at the top of the error plots' range inside an
    outage and at zero outside (a band's outline in every error plot)."""
    for k, (first, last) in enumerate(outages):
        strips = [track.pos[(track.t >= first) & (track.t <= last)] for track in fused]
        strips = [s for s in strips if len(s) >= 2]
        if strips:
            band = rr.LineStrips3D(strips, colors=colors.OUTAGE, radii=OUTAGE_LINE, labels=f"GPS outage {k + 1}")
            rec.log(f"world/gps_outage/{k}", band, static=True)
    t = fused[0].t
    during = np.zeros(len(t), dtype=bool)
    for first, last in outages:
        during |= (t >= first) & (t <= last)
    top = max((p.hi for p in plots.error if np.isfinite(p.hi)), default=1.0)
    _send_series(rec, "error/gps_outage", t, (during * top)[:, None], ["GPS outage"], [colors.OUTAGE])
    for plot in plots.error:
        plot.entities.append("error/gps_outage")


def _log_imu(rec, imu: ImuSeries, plots: _Plots) -> None:
    units = {"gyro": ("rad/s", "rad/s/√Hz"), "acc": ("m/s²", "m/s²/√Hz")}
    for sensor, (unit, sigma_unit) in units.items():
        series = [(f"imu/{sensor}", f"{sensor} (raw, {unit})", getattr(imu, sensor))]
        correction = getattr(imu, f"d_{sensor}")
        if correction is not None:
            series.append((f"correction/{sensor}", f"{sensor} correction ({unit})", correction))
        cov = getattr(imu, f"{sensor}_cov")
        if cov is not None:
            series.append((f"sigma/{sensor}", f"learned {sensor} σ ({sigma_unit})", np.sqrt(cov)))
        plots.sensors[sensor] = []
        for entity, title, values in series:
            _send_series(rec, entity, imu.t, values, list(colors.AXIS_NAMES), list(colors.AXES))
            plot = _Plot(title, [entity])
            plot.include(values)
            plots.sensors[sensor].append(plot)


def _send_series(rec, entity: str, t: np.ndarray, values: np.ndarray, names: list[str], rgb: list) -> None:
    """(N, C) scalars as C named, coloured series of one entity."""
    rec.log(entity, rr.SeriesLines(names=names, colors=rgb, widths=[1.5] * len(names)), static=True)
    values = np.ascontiguousarray(values, dtype=float)
    _send(rec, entity, t, rr.Scalars.columns(scalars=values if values.shape[1] > 1 else values[:, 0]))


def _send(rec, entity: str, t: np.ndarray, columns) -> None:
    rec.send_columns(entity, indexes=[rr.TimeColumn(TIMELINE, duration=np.asarray(t, dtype=float))], columns=columns)


def _send_ellipsoids(rec, entity: str, track: Track, color) -> None:
    """One ellipsoid per keyframe: principal axes of the position covariance, ``SIGMA_SCALE`` sigmas."""
    eigval, eigvec = np.linalg.eigh(track.pos_cov)
    eigvec = eigvec * np.sign(np.linalg.det(eigvec))[:, None, None]  # proper rotations
    half_sizes = SIGMA_SCALE * np.sqrt(np.clip(eigval, 0.0, None))
    quat_xyzw = np.roll(matrix_to_quat_wxyz(eigvec), -1, axis=-1)  # Rerun takes x, y, z, w
    _send(
        rec, entity, track.t, rr.Ellipsoids3D.columns(centers=track.pos, half_sizes=half_sizes, quaternions=quat_xyzw)
    )
    rec.log(entity, rr.Ellipsoids3D.from_fields(colors=color, line_radii=rr.Radius.ui_points(1.0)), static=True)


def _eye(pos: np.ndarray) -> rrb.EyeControls3D:
    """A camera looking down at the scene's centre from the south, about 55 degrees above the horizon."""
    lo, hi = pos.min(axis=0), pos.max(axis=0)
    centre, extent = (lo + hi) / 2, max(float(np.max(hi - lo)), 1.0)
    return rrb.EyeControls3D(
        kind=rrb.Eye3DKind.Orbital,
        look_target=centre,
        eye_up=(0.0, 0.0, 1.0),
        position=centre + extent * np.array([0.0, -0.75, 1.1]),
    )


def _blueprint(
    fused: list[Track], headline: str | None, plots: _Plots, eye: rrb.EyeControls3D, span: tuple[int, int] | None
) -> rrb.Blueprint:
    hidden = {
        f"/world/fused/{_slug(t.name)}/covariance": rrb.EntityBehavior(visible=False)
        for t in fused
        if t.name != headline
    }
    scene = rrb.Spatial3DView(
        name="trajectories (m)",
        origin="/world",
        contents=["+ /world/**", "- /world/dead_reckoning/**"],
        overrides=hidden,
        background=VIEW_BACKGROUND,
        eye_controls=eye,
    )
    drift_scene = rrb.Spatial3DView(
        name="dead reckoning (m)",
        origin="/world",
        background=VIEW_BACKGROUND,
        eye_controls=eye,
        contents=["+ /world/ground_truth", "+ /world/dead_reckoning/**"],
    )
    left = rrb.Tabs(scene, rrb.Vertical(drift_scene, *map(_view, plots.drift), name="dead reckoning"), active_tab=0)
    tabs = []
    if plots.error:
        overview, per_setting = plots.error[0], plots.error[1:]
        tabs.append(
            rrb.Vertical(
                _view(overview), rrb.Grid(*map(_view, per_setting)), row_shares=[1, 2], name="position error (m)"
            )
        )
    units = {"gyro": "gyro (rad/s)", "acc": "acc (m/s²)"}
    tabs += [rrb.Vertical(*map(_view, views), name=units[sensor]) for sensor, views in plots.sensors.items()]
    about = rrb.TextDocumentView(origin="/description", name="about this recording")
    left = rrb.Vertical(about, left, row_shares=[2, 5])
    layout = rrb.Horizontal(left, rrb.Tabs(*tabs, active_tab=0), column_shares=[3, 2]) if tabs else left
    selection = None if span is None else rr.encodings.AbsoluteTimeRange(*span)
    return rrb.Blueprint(
        layout,
        rrb.BlueprintPanel(state="collapsed"),  # its narrow tree cut the views' names; the views name themselves
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="expanded", timeline=TIMELINE, play_state="paused", time_selection=selection),
        auto_views=False,
    )


def _view(plot: _Plot) -> rrb.TimeSeriesView:
    """A time-series view of ``plot``'s entities, the y range leaving room at the top for the legend."""
    lo, hi = (plot.lo, plot.hi) if np.isfinite(plot.lo) else (0.0, 1.0)
    span = max(hi - lo, 1e-9)
    axis = rrb.ScalarAxis(range=(lo - 0.05 * span, hi + LEGEND_HEADROOM * span))
    return rrb.TimeSeriesView(
        name=plot.title,
        origin="/",
        contents=[f"+ /{e}" for e in plot.entities],
        axis_y=axis,
        plot_legend=rrb.PlotLegend(rrb.Corner2D.LeftTop),
    )


# (entity, metrics.jsonl keys, series names, colours, view title, legend corner: away from the curves' ends)
TRAINING_SERIES = (
    (
        "loss",
        ("train_loss", "val_loss"),
        ("train", "validation"),
        (colors.TRAIN, colors.VALIDATION),
        "loss",
        "RightTop",
    ),
    ("val/roe_deg", ("val_roe_deg",), ("validation ROE",), (colors.VALIDATION,), "validation ROE (deg)", "RightTop"),
    (
        "val/rpe_rmse_m",
        ("val_rpe_rmse_m",),
        ("validation RPE RMSE",),
        (colors.VALIDATION,),
        "validation RPE RMSE (m)",
        "RightTop",
    ),
    ("lr", ("lr",), ("learning rate",), (colors.TRAIN,), "learning rate", "RightTop"),
    ("seconds", ("seconds",), ("wall time",), (colors.TRAIN,), "time since the start (s)", "LeftTop"),
)


def write_training_recording(folder: str | Path, history: list[EpochLog]) -> Path:
    """``folder/training.rrd``: every epoch's losses and validation metrics (``metrics.jsonl`` entries), on the
    time line ``epoch`` (1 = the first). Written whole and atomically, so it is a valid recording whenever a viewer
    opens it, resumed runs included; ``learned_imu.training.experiment.train_run(on_epoch=...)`` calls it after each
    epoch."""
    path = Path(folder) / "training.rrd"
    history = [entry.to_dict() for entry in history]
    epochs = np.array([entry["epoch"] + 1 for entry in history], dtype=np.int64)
    views = []
    # an epoch of margin on both sides, so that the first and last epochs' markers are not cut by the plot's edge
    margin = rrb.TimeRange(rrb.TimeRangeBoundary.absolute(seq=0), rrb.TimeRangeBoundary.absolute(seq=len(epochs) + 1))
    with _saved(path, rr.RecordingStream("airimu-training", recording_id=str(Path(folder).resolve()))) as rec:
        for entity, keys, names, rgb, title, corner in TRAINING_SERIES:
            if not history or not all(key in history[0] for key in keys):
                continue
            values = np.array([[entry.get(key, np.nan) for key in keys] for entry in history], dtype=float)
            rec.log(entity, rr.SeriesLines(names=list(names), colors=list(rgb), widths=[2.0] * len(names)), static=True)
            rec.log(
                entity,
                rr.SeriesPoints(names=list(names), colors=list(rgb), marker_sizes=[3.0] * len(names)),
                static=True,
            )
            rec.send_columns(
                entity,
                indexes=[rr.TimeColumn("epoch", sequence=epochs)],
                columns=rr.Scalars.columns(scalars=values if len(keys) > 1 else values[:, 0]),
            )
            views.append(
                rrb.TimeSeriesView(
                    name=title,
                    origin=f"/{entity}",
                    axis_x=rrb.TimeAxis(view_range=margin),
                    plot_legend=rrb.PlotLegend(rrb.Corner2D[corner]),
                )
            )
        if history and all("val_loss" in entry for entry in history):  # the epoch best.pt holds, marked
            best = min(range(len(history)), key=lambda i: history[i]["val_loss"])
            rec.log(
                "loss/best",
                rr.SeriesPoints(
                    names=["best epoch (best.pt)"],
                    colors=[colors.GROUND_TRUTH],
                    markers=["diamond"],
                    marker_sizes=[8.0],
                ),
                static=True,
            )
            rec.set_time("epoch", sequence=int(epochs[best]))
            rec.log("loss/best", rr.Scalars(history[best]["val_loss"]))
            summary = (
                f"**training**\n\n{len(history)} epochs; best validation loss {history[best]['val_loss']:.5g} "
                f"at epoch {int(epochs[best])} (1 = the first): the weights best.pt holds."
            )
            stop = _early_stop(Path(folder), history, best)
            if stop is not None:  # the epoch the run stopped at, marked beside the best one
                marker = rr.SeriesPoints(
                    names=["early stop"], colors=[colors.VALIDATION], markers=["cross"], marker_sizes=[8.0]
                )
                rec.log("loss/early_stop", marker, static=True)
                rec.set_time("epoch", sequence=int(epochs[-1]))
                rec.log("loss/early_stop", rr.Scalars(history[-1]["val_loss"]))
                summary += (
                    f" Stopped early after epoch {int(epochs[-1])} of {stop[0]}: no lower validation loss "
                    f"in {stop[1]} epochs (train.early_stop_patience)."
                )
            rec.log("description", rr.TextDocument(summary, media_type=rr.MediaType.MARKDOWN), static=True)
            views.insert(0, rrb.TextDocumentView(origin="/description", name="about this run"))
        panels = (
            rrb.BlueprintPanel(state="collapsed"),
            rrb.SelectionPanel(state="collapsed"),
            rrb.TimePanel(state="collapsed", timeline="epoch"),
        )
        blueprint = rrb.Blueprint(rrb.Grid(*views), *panels, auto_views=False)
        rec.send_blueprint(blueprint, make_active=True)
    return path


def _early_stop(folder: Path, history: list[dict], best: int) -> tuple[int, int] | None:
    """(planned epochs, patience) when the run in ``folder`` (its ``config.yaml``) stopped early at the last epoch of
    ``history`` (the rule of ``train_run``), else None; None without a readable config too."""
    from airimu_core.errors import AirImuError
    from learned_imu.config import load_config

    try:
        train = load_config(folder / "config.yaml").train
    except (AirImuError, OSError):
        return None
    patience = train.early_stop_patience
    stalled = stopped_early(history[-1]["epoch"], history[best]["epoch"], patience)
    return (train.epochs, patience) if stalled and len(history) < train.epochs else None


@contextmanager
def _saved(path: Path, rec: rr.RecordingStream) -> Iterator[rr.RecordingStream]:
    """``rec`` saving to a temporary file beside ``path``, renamed to ``path`` once everything is logged (rerun
    writes the file itself, so ``airimu_core.io.atomic_file`` cannot be used); removed on error."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        rec.save(str(tmp))
        yield rec
        rec.flush()
        rec.disconnect()
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)


def _at(track: Track, t: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(t, track.t, track.pos[:, i]) for i in range(3)])


def _slug(name: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")

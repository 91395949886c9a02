"""The Rerun recording read back from the file: the blueprint's views and entity filters, and the logged names,
colours and values (small synthetic tracks; ``tests/fusion/test_pgo.py`` reads one of a real ablation)."""

from __future__ import annotations

import re
from collections import defaultdict
from dataclasses import replace

import numpy as np
import pytest

from airimu.viz import colors

SETTINGS = ("raw IMU + fixed cov", "AirIMU + fixed cov", "raw IMU + learned cov", "AirIMU + learned cov")


def _rgba(color) -> int:
    r, g, b = color
    return (r << 24) | (g << 16) | (b << 8) | 255


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """Ground truth on a circle, four fused settings each a known constant offset from it with a known isotropic
    covariance, two dead-reckoning tracks drifting away, GPS fixes and IMU series."""
    from airimu.viz.recording import ImuSeries, Track, write_recording

    t = np.linspace(0.0, 10.0, 101)
    truth = Track("ground truth", t, np.column_stack([np.cos(t), np.sin(t), 0.1 * t]))
    fused = []
    for i, name in enumerate(SETTINGS):
        offset = 0.01 * (i + 1)
        cov = np.repeat(np.diag([0.01, 0.01, 0.04 * (i + 1)])[None], len(t), axis=0)
        fused.append(Track(name, t, truth.pos + [offset, 0.0, 0.0], cov))
    drift = [Track("raw IMU", t, truth.pos + t[:, None] ** 2), Track("AirIMU", t, truth.pos + 0.1 * t[:, None])]
    rng = np.random.default_rng(0)
    n = np.linspace(0.0, 10.0, 2001)
    imu = ImuSeries(
        n,
        0.4 * rng.standard_normal((len(n), 3)),
        9.8 + rng.standard_normal((len(n), 3)),
        np.full((len(n), 3), 1e-3),
        np.full((len(n), 3), 1e-2),
        np.full((len(n), 3), 4e-6),
        np.full((len(n), 3), 1e-4),
    )
    path = write_recording(
        tmp_path_factory.mktemp("rec") / "run.rrd", fused, truth, drift, (t[::10], truth.pos[::10]), imu
    )
    return path, t


def _entities(path, blueprint: bool = False) -> dict[str, dict[str, list]]:
    """Every entity's columns (archetype:component -> rows), chunks concatenated; of the recording, or of the
    blueprint store the file carries beside it."""
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    stream = reader.stream(store=reader.blueprints()[0]) if blueprint else reader.stream()
    out = defaultdict(lambda: defaultdict(list))
    for chunk in stream.to_chunks():
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if ":" in name:
                out[chunk.entity_path][name] += batch.column(name).to_pylist()
    return out


def _views(blueprint) -> dict[str, dict]:
    """Views by display name: class, origin, contents query and per-entity overrides."""
    views = {}
    for path, columns in blueprint.items():
        if "ViewBlueprint:display_name" in columns:
            views[columns["ViewBlueprint:display_name"][-1][0]] = {
                "class": columns["ViewBlueprint:class_identifier"][-1][0],
                "origin": columns["ViewBlueprint:space_origin"][-1][0],
                "query": blueprint[f"{path}/ViewContents"]["ViewContents:query"][-1],
                "hidden": sorted(
                    p.split("/ViewContents/overrides")[1].removesuffix("/visualizers")
                    for p, c in blueprint.items()
                    if p.startswith(f"{path}/ViewContents/overrides/") and c.get("EntityBehavior:visible") == [[False]]
                ),
            }
    return views


def test_blueprint_views_and_entity_filters(recording):
    path, _ = recording
    blueprint = _entities(path, blueprint=True)
    views = _views(blueprint)
    scene = views["trajectories (m)"]
    assert scene["class"] == "3D" and scene["origin"] == "/world"
    assert scene["query"] == ["+ /world/**", "- /world/dead_reckoning/**"]  # dead reckoning out of the 3-D view
    # only the headline setting's ellipsoids are visible by default
    assert scene["hidden"] == sorted(
        f"/world/fused/{s}/covariance" for s in ("raw_imu_fixed_cov", "airimu_fixed_cov", "raw_imu_learned_cov")
    )
    drift = views["dead reckoning (m)"]
    assert drift["class"] == "3D" and "+ /world/dead_reckoning/**" in drift["query"]
    # plots split by unit, the unit in every title
    expected = {
        "gyro (raw, rad/s)": ["+ /imu/gyro"],
        "acc (raw, m/s²)": ["+ /imu/acc"],
        "gyro correction (rad/s)": ["+ /correction/gyro"],
        "acc correction (m/s²)": ["+ /correction/acc"],
        "learned gyro σ (rad/s/√Hz)": ["+ /sigma/gyro"],
        "learned acc σ (m/s²/√Hz)": ["+ /sigma/acc"],
        "AirIMU + learned cov (m)": ["+ /error/position/airimu_learned_cov", "+ /error/sigma3/airimu_learned_cov"],
        "dead-reckoning drift from ground truth (m)": [
            "+ /error/dead_reckoning/raw_imu",
            "+ /error/dead_reckoning/airimu",
        ],
    }
    for name, query in expected.items():
        assert views[name]["class"] == "TimeSeries" and views[name]["query"] == query, name
    overview = views["position error, all settings (m)"]["query"]
    slugs = ("raw_imu_fixed_cov", "airimu_fixed_cov", "raw_imu_learned_cov", "airimu_learned_cov")
    assert overview == [f"+ /error/position/{s}" for s in slugs]
    # the time panel expanded (PanelState 3), on the time line "time"; the blueprint tree collapsed (2): it cut names
    assert blueprint["/blueprint_panel"]["PanelBlueprint:state"] == [[2]]
    assert blueprint["/time_panel"]["TimePanelBlueprint:state"] == [[3]]
    assert blueprint["/time_panel"]["TimePanelBlueprint:timeline"] == [["time"]]
    # tabs per sensor on the plot side
    tabs = {
        c["ContainerBlueprint:display_name"][-1][0]
        for c in blueprint.values()
        if "ContainerBlueprint:display_name" in c
    }
    assert {"position error (m)", "gyro (rad/s)", "acc (m/s²)", "dead reckoning"} <= tabs


def test_names_colours_and_entity_paths(recording):
    path, _ = recording
    entities = _entities(path)
    assert not [e for e in entities if e.endswith("/norm") or e.endswith("/x")]  # series are named, not leaves
    assert "/world/dead_reckoning/raw_imu" in entities and "/world/dead_reckoning/airimu" in entities
    assert not [e for e in entities if e.startswith("/world/raw") or e.startswith("/world/airimu")]
    truth = entities["/world/ground_truth"]
    assert truth["LineStrips3D:colors"] == [[_rgba(colors.GROUND_TRUTH)]]
    assert truth["LineStrips3D:labels"] == [["ground truth"]] and truth["LineStrips3D:show_labels"] == [[True]]
    assert entities["/world/gps"]["Points3D:colors"] == [[_rgba(colors.GPS)]]
    palette = set()
    for setting in SETTINGS:
        slug = setting.lower().replace(" + ", "_").replace(" ", "_")
        color = _rgba(colors.setting_color(setting))
        palette.add(color)
        # one colour per setting, shared by its line, marker, ellipsoid and error curve
        assert entities[f"/world/fused/{slug}"]["LineStrips3D:colors"] == [[color]], setting
        assert entities[f"/world/fused/{slug}/now"]["Points3D:colors"] == [[color]], setting
        assert entities[f"/world/fused/{slug}/covariance"]["Ellipsoids3D:colors"] == [[color]], setting
        assert entities[f"/error/position/{slug}"]["SeriesLines:colors"] == [[color]], setting
        assert entities[f"/error/position/{slug}"]["SeriesLines:names"] == [[setting]], setting
        assert entities[f"/error/sigma3/{slug}"]["SeriesLines:names"] == [[f"{setting}: 3σ"]], setting
    assert len(palette) == len(SETTINGS)
    axes = [_rgba(c) for c in colors.AXES]
    for entity in ("/imu/gyro", "/imu/acc", "/correction/gyro", "/correction/acc", "/sigma/gyro", "/sigma/acc"):
        assert entities[entity]["SeriesLines:names"] == [["x", "y", "z"]], entity
        assert entities[entity]["SeriesLines:colors"] == [axes], entity  # x/y/z alike in every plot
        assert len(entities[entity]["Scalars:scalars"]) == 2001 and len(entities[entity]["Scalars:scalars"][0]) == 3


def test_errors_bounds_markers_and_gps_on_the_time_line(recording):
    path, t = recording
    entities = _entities(path)
    for i, setting in enumerate(SETTINGS):
        slug = setting.lower().replace(" + ", "_").replace(" ", "_")
        error = np.ravel(entities[f"/error/position/{slug}"]["Scalars:scalars"])
        np.testing.assert_allclose(error, 0.01 * (i + 1), atol=1e-12)  # the known offset
        bound = np.ravel(entities[f"/error/sigma3/{slug}"]["Scalars:scalars"])
        np.testing.assert_allclose(bound, 3 * np.sqrt(max(0.01, 0.04 * (i + 1))), rtol=1e-12)
        assert len(entities[f"/world/fused/{slug}/now"]["Points3D:positions"]) == len(t)  # a marker per keyframe
    drift = np.ravel(entities["/error/dead_reckoning/raw_imu"]["Scalars:scalars"])
    np.testing.assert_allclose(drift, np.sqrt(3) * t**2, rtol=1e-9)
    assert len(entities["/world/gps/fix"]["Points3D:positions"]) == 11  # every fix at its time
    assert len(entities["/world/ground_truth/now"]["Points3D:positions"]) == len(t)


def test_colour_families():
    airimu = [colors.setting_color(s) for s in SETTINGS if s.startswith("AirIMU")]
    raw = [colors.setting_color(s) for s in SETTINGS if s.startswith("raw")]
    assert all(b > r for r, _, b in airimu) and all(r > b for r, _, b in raw)  # blues and reds
    names = [*SETTINGS, *(f"{s} + bias states" for s in SETTINGS), "GTSAM example (raw IMU + bias states)", "fused"]
    palette = colors.setting_colors(names)
    assert len(set(palette.values())) == len(names)
    assert colors.headline(names) == "AirIMU + learned cov" and colors.headline(["fused"]) == "fused"


TINY = """
name: tiny
data:
  train: [{dataset: simulator, options: {duration_s: 8.0, seed: 1, device_seed: 5}}]
  val: [{dataset: simulator, options: {duration_s: 6.0, seed: 2, device_seed: 5}}]
model: {conv_channels: [8, 16], gru_sizes: [16], decoder_hidden: 16}
train: {window: 200, every: 50, batch_size: 4, epochs: 2, lr: 3e-3, calibration_steps: 0}
"""


@pytest.mark.slow  # trains two epochs
def test_training_is_drawn_in_rerun_and_logged_one_line_per_epoch(tmp_path, capsys):
    import json

    from airimu.viz.recording import write_training_recording
    from learned_imu.config import load_config
    from learned_imu.training.experiment import train_run

    (tmp_path / "tiny.yaml").write_text(TINY)
    calls = []

    def on_epoch(folder, history):
        calls.append(len(history))
        write_training_recording(folder, history)

    train_run(load_config(tmp_path / "tiny.yaml"), tmp_path / "run", progress=True, on_epoch=on_epoch)
    assert calls == [1, 2]  # after every epoch, with the metrics so far
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if " epoch " in line]
    assert [line.split(":")[0] for line in lines] == ["tiny epoch 1/2", "tiny epoch 2/2"]  # stderr is no terminal
    assert "\r" not in err and "batch/s" not in err  # no redrawn progress bars in a log
    history = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    entities = _entities(tmp_path / "run" / "training.rrd")
    assert entities["/loss"]["SeriesLines:names"] == [["train", "validation"]]
    np.testing.assert_allclose(
        entities["/loss"]["Scalars:scalars"], [[h["train_loss"], h["val_loss"]] for h in history]
    )
    roe = np.ravel(entities["/val/roe_deg"]["Scalars:scalars"])
    np.testing.assert_allclose(roe, [h["val_roe_deg"] for h in history])
    views = _views(_entities(tmp_path / "run" / "training.rrd", blueprint=True))
    assert {"loss", "validation ROE (deg)", "validation RPE RMSE (m)", "learning rate"} <= set(views)


def test_the_recording_explains_itself(recording):
    """A text panel says what the recording is and scores every setting; each track is labelled at its end (told
    apart without colour); the time panel opens paused on the whole run, not at the last keyframe."""
    path, t = recording
    entities = _entities(path)
    text = entities["/description"]["TextDocument:text"][-1][0]
    for i, name in enumerate(SETTINGS):
        assert f"| {name} | {0.01 * (i + 1):.3f} |" in text  # its constant offset from the truth is its ATE
    assert "101 keyframes over 10.0 s; ground truth: yes; GPS fixes fused: 11" in text
    at = []
    for name in SETTINGS:
        slug = re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")
        label = entities[f"/world/fused/{slug}/label"]
        assert label["Points3D:labels"][-1] == [name] and label["Points3D:show_labels"][-1] == [True]
        at.append(np.ravel(label["Points3D:positions"][-1]))
    # the names stand apart (the tracks end 1 cm from each other, where the names overlapped): > 0.3 m here
    assert min(np.linalg.norm(a - b) for i, a in enumerate(at) for b in at[i + 1 :]) > 0.3
    blueprint = _entities(path, blueprint=True)
    assert _views(blueprint)["about this recording"]["class"] == "TextDocument"
    selection = blueprint["/time_panel"]["TimePanelBlueprint:time_selection"][-1][0]
    assert (selection["min"], selection["max"]) == (0, int(round(t[-1] * 1e9)))


def test_the_training_recording_marks_the_epoch_best_pt_holds(tmp_path):
    from airimu.viz.recording import write_training_recording
    from learned_imu.training.train import EpochLog

    losses = [0.9, 0.5, 0.3, 0.35, 0.4]
    history = [EpochLog(i, 1.0 - 0.1 * i, v, 1e-3, seconds=float(i)) for i, v in enumerate(losses)]
    path = write_training_recording(tmp_path, history)
    entities = _entities(path)
    assert np.ravel(entities["/loss/best"]["Scalars:scalars"]).tolist() == [0.3]
    assert entities["/loss/best"]["SeriesPoints:names"] == [["best epoch (best.pt)"]]
    text = entities["/description"]["TextDocument:text"][-1][0]
    assert "5 epochs; best validation loss 0.3 at epoch 3" in text
    assert "about this run" in _views(_entities(path, blueprint=True))
    assert "/loss/early_stop" not in entities  # no config.yaml in the folder: nothing says the run stopped early


def test_the_training_recording_marks_an_early_stop(tmp_path):
    """A run that stopped early (its config's patience) says so: a cross on the loss at the last epoch, a sentence."""
    from airimu.viz.recording import write_training_recording
    from learned_imu.config import load_config, save_config
    from learned_imu.training.train import EpochLog

    (tmp_path / "tiny.yaml").write_text(TINY)
    config = load_config(tmp_path / "tiny.yaml")
    config = replace(config, train=replace(config.train, epochs=20, early_stop_patience=2))
    save_config(tmp_path / "config.yaml", config)
    losses = [0.9, 0.5, 0.3, 0.35, 0.4]  # best at epoch 3, two epochs without a lower one: train_run stops
    history = [EpochLog(i, 1.0 - 0.1 * i, v, 1e-3, seconds=float(i)) for i, v in enumerate(losses)]
    entities = _entities(write_training_recording(tmp_path, history))
    assert np.ravel(entities["/loss/early_stop"]["Scalars:scalars"]).tolist() == [0.4]
    assert entities["/loss/early_stop"]["SeriesPoints:names"] == [["early stop"]]
    text = entities["/description"]["TextDocument:text"][-1][0]
    assert "Stopped early after epoch 5 of 20: no lower validation loss in 2 epochs" in text
    entities = _entities(write_training_recording(tmp_path, history[:4]))  # one epoch short of the patience
    assert "/loss/early_stop" not in entities


def test_the_per_setting_error_plots_share_one_y_range(recording):
    path, _ = recording
    blueprint = _entities(path, blueprint=True)
    ranges = {}
    for view, columns in blueprint.items():
        name = columns.get("ViewBlueprint:display_name", [[None]])[-1][0]
        if name in {f"{s} (m)" for s in SETTINGS}:
            ranges[name] = tuple(blueprint[f"{view}/ScalarAxis"]["ScalarAxis:range"][-1][0])
    assert len(ranges) == 4 and len(set(ranges.values())) == 1, ranges

"""What the toolkit refuses, one test per class of bad input (README "What it refuses"): each case ends in one
clear error naming the file, field, key or flag, never a traceback, a silently wrong result or a hang.

CLI cases run ``airimu.cli.main`` in-process (the console script's entry point) and read its exit code and stderr.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from airimu.cli import main
from airimu_core.errors import ConfigError, DataError, ExportError, GraphError, InputError
from airimu_core.export import load_export
from airimu_core.io import atomic_file, output_folder, write_json_atomic
from airimu_core.rotations import matrix_to_quat_wxyz
from factors.export_file import from_export
from learned_imu.config import ModelConfig, load_config
from learned_imu.datasets import read_sequence
from learned_imu.datasets.simulator import simulate
from learned_imu.export import export_preintegration, keyframes_every
from learned_imu.network.checkpoint import build_model, model_from_checkpoint
from tests.helpers import write_checkpoint

CSV_KEYS = dict(header=True, time="t", gyro=["gx", "gy", "gz"], acc=["ax", "ay", "az"])
GT_KEYS = dict(gt_pos=["px", "py", "pz"], gt_quat=["qw", "qx", "qy", "qz"], gt_vel=["vx", "vy", "vz"])
HEADER = "t,gx,gy,gz,ax,ay,az,px,py,pz,qw,qx,qy,qz,vx,vy,vz"


@pytest.fixture(scope="module")
def flight():
    return simulate("drone", duration_s=30.0, rate_hz=100.0, gps_rate_hz=1.0, gps_sigma_m=0.1, seed=1)


def write_csv(path: Path, seq, pos_scale: float = 1.0, vel_scale: float = 1.0) -> Path:
    """The flight as a generic CSV with ground truth (position scaled, velocity scaled: units and signs)."""
    quat = matrix_to_quat_wxyz(seq.gt.rot)
    rows = np.column_stack([seq.t, seq.gyro, seq.acc, pos_scale * seq.gt.pos, quat, vel_scale * seq.gt.vel])
    np.savetxt(path, rows, delimiter=",", header=HEADER, comments="")
    return path


@pytest.fixture(scope="module")
def files(flight, tmp_path_factory):
    folder = tmp_path_factory.mktemp("refusals")
    write_csv(folder / "imu.csv", flight)
    np.savetxt(
        folder / "imu_only.csv",
        np.column_stack([flight.t, flight.gyro, flight.acc]),
        delimiter=",",
        header="t,gx,gy,gz,ax,ay,az",
        comments="",
    )
    gps = flight.gps
    for name, rows in {"gps.csv": slice(None), "gps_two_close.csv": slice(0, 2)}.items():
        np.savetxt(
            folder / name, np.column_stack([gps.t[rows], gps.pos[rows]]), delimiter=",", header="t,x,y,z", comments=""
        )
    (folder / "empty.mat").write_bytes(b"")
    (folder / "random.bag").write_bytes(np.random.default_rng(0).bytes(5000))
    (folder / "random.csv").write_bytes(np.random.default_rng(1).bytes(5000))
    (folder / "a_folder").mkdir()
    return folder


def cli(capsys, monkeypatch, *args: str) -> tuple[int, str]:
    """Run ``airimu ARGS`` in-process; (exit code, stderr)."""
    monkeypatch.setattr(sys, "argv", ["airimu", *map(str, args)])
    monkeypatch.delenv("AIRIMU_DEBUG", raising=False)
    with pytest.raises(SystemExit) as ended:
        main()
    return ended.value.code, capsys.readouterr().err


def reader_options(keys: dict) -> list[str]:
    out = []
    for key, value in keys.items():
        text = f"[{','.join(value)}]" if isinstance(value, list) else str(value).lower()
        out += ["--reader-option", f"{key}={text}"]
    return out


# ---- CLI values and flags: refused before any work, naming the flag -------------------------------------------


CLI_CASES = {
    "unknown dataset": (["evaluate", "--dataset", "foo", "--path", "{imu}"], "unknown reader 'foo'"),
    "interval 0": (["evaluate", "--dataset", "csv", "--path", "{imu}", "--interval", "0"], "--interval must be"),
    "interval unit": (
        ["evaluate", "--dataset", "csv", "--path", "{imu}", "--interval-unit", "minutes"],
        "--interval-unit must be",
    ),
    "keyframes 0s": (
        [
            "export",
            "--dataset",
            "csv",
            "--path",
            "{imu_only}",
            "--out",
            "{tmp}/e.npz",
            "--keyframes",
            "0s",
            "--gyro-noise-density",
            "0.004",
            "--acc-noise-density",
            "0.08",
            *reader_options(CSV_KEYS),
        ],
        "keyframes: interval must be positive",
    ),
    "keyframes 5000s": (
        [
            "export",
            "--dataset",
            "csv",
            "--path",
            "{imu_only}",
            "--out",
            "{tmp}/e.npz",
            "--keyframes",
            "5000s",
            "--gyro-noise-density",
            "0.004",
            "--acc-noise-density",
            "0.08",
            *reader_options(CSV_KEYS),
        ],
        "--keyframes 5000s: the interval is longer than the recording",
    ),
    "keyframes abc": (
        [
            "export",
            "--dataset",
            "csv",
            "--path",
            "{imu_only}",
            "--out",
            "{tmp}/e.npz",
            "--keyframes",
            "abc",
            "--gyro-noise-density",
            "0.004",
            "--acc-noise-density",
            "0.08",
            *reader_options(CSV_KEYS),
        ],
        "'abc' is neither",
    ),
    "negative density": (
        [
            "export",
            "--dataset",
            "csv",
            "--path",
            "{imu_only}",
            "--out",
            "{tmp}/e.npz",
            "--gyro-noise-density",
            "-1.7e-4",
            "--acc-noise-density",
            "0.08",
        ],
        "--gyro-noise-density",
    ),
    "gps every 0": (
        ["fuse", "--dataset", "csv", "--path", "{imu}", "--out", "{tmp}/f", "--gps-every", "0"],
        "--gps-every must be",
    ),
    "fuse keyframes 5000s": (
        [
            "fuse",
            "--dataset",
            "csv",
            "--path",
            "{imu_only}",
            "--gps",
            "{gps}",
            "--out",
            "{tmp}/f",
            "--keyframes",
            "5000s",
        ],
        "--keyframes 5000s: the interval is longer than the recording",
    ),
    "fuse keyframes 1e308s": (
        [
            "fuse",
            "--dataset",
            "csv",
            "--path",
            "{imu_only}",
            "--gps",
            "{gps}",
            "--out",
            "{tmp}/f",
            "--keyframes",
            "1e308s",
        ],
        "the interval is longer than the recording",
    ),
    "gps time offset nan": (
        [
            "fuse",
            "--dataset",
            "csv",
            "--path",
            "{imu_only}",
            "--gps",
            "{gps}",
            "--out",
            "{tmp}/f",
            "--gps-time-offset",
            "nan",
        ],
        "--gps-time-offset: expected seconds within +-3600",
    ),
    "reader option typo": (
        ["evaluate", "--dataset", "csv", "--path", "{imu}", "--reader-option", "sede=1"],
        "reader option 'sede': csv has no such option",
    ),
    "reader option type": (
        ["evaluate", "--dataset", "csv", "--path", "{imu}", "--reader-option", "gravity=up"],
        "reader option 'gravity': expected float",
    ),
    "reader option form": (
        ["evaluate", "--dataset", "csv", "--path", "{imu}", "--reader-option", "gravity"],
        "expected key=value",
    ),
    "json is a folder": (["evaluate", "--dataset", "csv", "--path", "{imu}", "--json", "{tmp}"], "is a folder"),
    "out is a file": (["fuse", "--dataset", "csv", "--path", "{imu}", "--out", "{imu}"], "--out: "),
    "export out is a folder": (["export", "--dataset", "csv", "--path", "{imu}", "--out", "{tmp}"], "is a folder"),
    "pgo epochs 0": (["ablate-pgo", "--config", "pgo_demo.yaml", "--epochs", "0"], "--epochs must be at least 1"),
    "pgo rrd is a folder": (["ablate-pgo", "--config", "pgo_demo.yaml", "--rrd", "{tmp}"], "--rrd: "),
    "train out is a file": (["train", "--config", "demo.yaml", "--out", "{imu}"], "--out: "),
    "config not text": (["train", "--config", "{binary}", "--out", "{tmp}/r"], "not a text file in UTF-8"),
    "view a csv": (["view", "{imu}"], "not a Rerun recording (an .rrd starts with 'RRF'"),
}


@pytest.mark.parametrize("case", sorted(CLI_CASES))
def test_cli_values_are_refused_naming_the_flag(case, files, tmp_path, capsys, monkeypatch):
    args, message = CLI_CASES[case]
    paths = {
        "imu": files / "imu.csv",
        "imu_only": files / "imu_only.csv",
        "gps": files / "gps.csv",
        "tmp": tmp_path,
        "binary": files / "random.csv",
    }
    code, err = cli(capsys, monkeypatch, *(a.format(**paths) for a in args))
    assert code == 2
    assert message in " ".join(err.replace("│", " ").split())  # typer boxes and wraps its message
    assert "Traceback" not in err


# capsys and monkeypatch are shared by the examples: each call reads (and so resets) stderr, and patches in a context
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(interval=st.one_of(st.floats(max_value=0.0), st.just(float("nan")), st.just(float("inf"))))
def test_cli_interval_any_non_positive_or_non_finite_number(interval, capsys, monkeypatch):
    with monkeypatch.context() as patch:
        code, err = cli(capsys, patch, "evaluate", "--dataset", "csv", "--path", "x.csv", "--interval", repr(interval))
    assert code == 2 and "--interval must be a positive number" in err and "Traceback" not in err


# ---- data the toolkit cannot use: one line naming the file and field --------------------------------------------


FILE_CASES = {
    "zero-byte mat": ("broad", "empty.mat", [], "cannot be read as broad"),
    "random-byte bag": ("rosbag", "random.bag", [], "cannot be read as rosbag"),
    "random-byte csv": ("csv", "random.csv", [], "random.csv"),
    "folder as csv": ("csv", "a_folder", [], "a_folder"),
    "missing file": ("csv", "nothing.csv", [], "no such file or folder"),
    "no ground truth to evaluate": ("csv", "imu_only.csv", reader_options(CSV_KEYS), "needs ground truth"),
}


@pytest.mark.parametrize("case", sorted(FILE_CASES))
def test_unreadable_files_are_one_line_naming_the_file(case, files, capsys, monkeypatch):
    dataset, name, options, message = FILE_CASES[case]
    code, err = cli(capsys, monkeypatch, "evaluate", "--dataset", dataset, "--path", files / name, *options)
    assert code == 2 and err.startswith("airimu: error: ") and err.count("\n") == 1, err
    assert message in err and "Traceback" not in err


def test_graph_and_export_errors_print_as_one_line(files, tmp_path, capsys, monkeypatch):
    args = [
        "fuse",
        "--dataset",
        "csv",
        "--path",
        files / "imu_only.csv",
        "--gps",
        files / "gps_two_close.csv",
        "--out",
        tmp_path / "f",
        *reader_options(CSV_KEYS),
    ]
    code, err = cli(capsys, monkeypatch, *args)
    assert code == 2 and err.startswith("airimu: error: ") and "under-constrained" in err and "Traceback" not in err
    assert not (tmp_path / "f" / "fused.tum").exists()


# ---- config values: reader and simulator options are bounded and typed -------------------------------------------


OPTION_CASES = {
    "reader typo": ("{dataset: euroc, path: x, options: {imu_fle: a.csv}}", "options 'imu_fle'"),
    "simulator typo": ("{dataset: simulator, options: {sede: 3}}", "options 'sede'"),
    "wrong type": ("{dataset: simulator, options: {duration_s: long}}", "options 'duration_s': expected float"),
    "unknown dataset": ("{dataset: tum_vi, path: x}", "unknown dataset 'tum_vi'"),
    "not a mapping": ("{dataset: simulator, options: [1, 2]}", "expected a mapping"),
    "object option": ("{dataset: simulator, options: {error_model: {gyro: 1}}}", "options 'error_model'"),
    "zero rate": ("{dataset: simulator, options: {rate_hz: 0}}", "options 'rate_hz': expected a positive number"),
    "negative duration": ("{dataset: simulator, options: {duration_s: -5}}", "options 'duration_s': expected a pos"),
    "NaN GPS sigma": ("{dataset: simulator, options: {gps_sigma_m: .nan}}", "options 'gps_sigma_m': expected a pos"),
    "unknown profile": ("{dataset: simulator, options: {profile: boat}}", "options 'profile': expected one of"),
    "unknown gap policy": ("{dataset: euroc, path: x, options: {on_gap: skip}}", "options 'on_gap': expected one of"),
    "unknown unit": ("{dataset: csv, path: x, options: {time_unit: minutes}}", "options 'time_unit': expected one"),
}


def refused_config(folder: Path, text: str, message: str) -> str:
    """The ConfigError of loading ``text`` as a config file (it must match ``message`` and name the file)."""
    path = folder / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message) as error:
        load_config(path)
    assert str(path) in str(error.value)
    return str(error.value)


@pytest.mark.parametrize("case", sorted(OPTION_CASES))
def test_sequence_options_are_checked_against_the_signature(case, tmp_path):
    spec, message = OPTION_CASES[case]
    text = f"name: x\ndata:\n  train: [{spec}]\n  val: [{{dataset: simulator}}]\n"
    assert "data.train[0]" in refused_config(tmp_path, text, message)


NON_POSITIVE = st.one_of(st.floats(max_value=0.0), st.sampled_from([float("nan"), float("inf"), -float("inf")]))
BAD_NUMBERS = {
    "train.lr": NON_POSITIVE,
    "train.batch_size": st.integers(max_value=0),
    "train.epochs": st.integers(max_value=0),
    "train.window": st.integers(max_value=1),
    "train.plateau_factor": st.one_of(st.floats(min_value=1.0), st.floats(max_value=0.0)),
    "model.dropout": st.one_of(st.floats(min_value=1.0), st.floats(max_value=-1e-9)),
    "evaluation.interval": NON_POSITIVE,
    "loss.covariance": st.one_of(st.floats(max_value=-1e-12), st.just(float("nan"))),
}


@pytest.mark.parametrize("key", sorted(BAD_NUMBERS))
@settings(max_examples=15, deadline=None)
@given(data=st.data())
def test_config_numbers_out_of_range_name_the_key(key, data):
    import tempfile

    import yaml

    section, name = key.split(".")
    value = data.draw(BAD_NUMBERS[key], label=key)
    config = {
        "name": "x",
        "data": {"train": [{"dataset": "simulator"}], "val": [{"dataset": "simulator"}]},
        section: {name: value},
    }
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "bad.yaml"
        path.write_text(yaml.safe_dump(config))
        with pytest.raises(ConfigError, match=key.replace(".", r"\.")) as error:
            load_config(path)
    assert str(path) in str(error.value)


def test_nested_yaml_aliases_are_refused_before_they_expand(tmp_path):
    """~10^9 elements in a few hundred bytes: refused by size, never expanded (``dataclasses.asdict`` hung on it)."""
    levels = ["a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    levels += [
        f"a{i}: &a{i} [*a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, "
        f"*a{i - 1}, *a{i - 1}, *a{i - 1}]"
        for i in range(1, 9)
    ]
    body = "\n".join(f"      {line}" for line in levels)
    path = tmp_path / "bomb.yaml"
    path.write_text(f"name: x\ndata:\n  train:\n  - dataset: simulator\n    options:\n{body}\n  val: []\n")
    with pytest.raises(ConfigError, match="more than 1000 values or nested deeper"):
        load_config(path)


# ---- exports: every backend refuses what LearnedImuFactor refuses --------------------------------------------------


@pytest.fixture(scope="module")
def exported(flight, tmp_path_factory):
    path = tmp_path_factory.mktemp("export") / "seq.npz"
    return export_preintegration(path, flight, keyframes_every(flight, 0.5), 1e-6, 1e-4)


def _corrupted(src: Path, dst: Path, field: str, change) -> Path:
    with np.load(src, allow_pickle=False) as data:
        arrays = {k: data[k].copy() for k in data.files}
    change(arrays[field])
    np.savez(dst, **arrays)
    return dst


def _set(index, value):
    def change(a):
        a[index] = value

    return change


EXPORT_CASES = {
    "zero covariance": ("delta_cov", _set(3, 0.0), "positive definite"),
    "asymmetric covariance": ("delta_cov", _set((3, 0, 5), 1.0), "positive definite"),
    "negative variance": ("delta_cov", _set((3, 4, 4), -1e-3), "positive definite"),
    "zero delta_dt": ("delta_dt", _set(2, 0.0), "delta_dt must be positive"),
    "negative delta_dt": ("delta_dt", _set(2, -0.5), "delta_dt must be positive"),
    "not a rotation": ("delta_rot", _set((1, 0, 0), 2.0), "not a rotation"),
    "unsorted keyframes": (
        "keyframe_index",
        lambda a: a.__setitem__(slice(2, 4), a[2:4][::-1].copy()),
        "keyframe_index",
    ),
    "keyframe past the end": ("keyframe_index", _set(-1, 10**6), "keyframe_index"),
    "gravity up": ("gravity", lambda a: a.__imul__(-1.0), "does not point down"),
    "zero gravity": ("gravity", _set(slice(None), 0.0), "magnitude"),
    "gravity in g": ("gravity", lambda a: a.__imul__(1 / 9.81), "magnitude"),
    "zero noise density": ("gyro_cov", _set(5, 0.0), "'gyro_cov'"),
}


@pytest.mark.parametrize("backend", ["gtsam", "custom"])
@pytest.mark.parametrize("case", sorted(EXPORT_CASES))
def test_bad_exports_are_refused_on_every_backend(case, backend, exported, tmp_path):
    field, change, message = EXPORT_CASES[case]
    bad = _corrupted(exported, tmp_path / "bad.npz", field, change)
    with pytest.raises(ExportError, match=message) as error:
        from_export(bad, backend=backend, bias_key=None if backend == "custom" else (lambda k: k))
    assert "bad.npz" in str(error.value)
    assert load_export(exported).delta_dt.size > 0  # the uncorrupted file still loads


# ---- ground truth in other units or signs: the motion self-check names the field ---------------------------------


@pytest.mark.parametrize(
    ("pos_scale", "vel_scale", "field", "hint"),
    [
        (1000.0, 1000.0, "gt.vel", "in mm"),
        (100.0, 100.0, "gt.vel", "in cm"),
        (0.001, 0.001, "gt.vel", "in km"),
        (1.0, -1.0, "gt.vel", "negated"),
        (1000.0, 1.0, "gt.pos", "in mm"),
    ],
)
def test_ground_truth_units_and_signs_are_caught(pos_scale, vel_scale, field, hint, flight, tmp_path):
    path = write_csv(tmp_path / "gt.csv", flight, pos_scale, vel_scale)
    with pytest.raises(DataError, match=hint) as error:
        read_sequence("csv", path, **CSV_KEYS, **GT_KEYS)
    assert error.value.field == field and "gt.csv" in str(error.value)
    read_sequence("csv", write_csv(tmp_path / "ok.csv", flight), **CSV_KEYS, **GT_KEYS)  # the same data in m, m/s


def test_positions_in_mm_without_a_velocity_column(flight, tmp_path):
    path = write_csv(tmp_path / "mm.csv", flight, 1000.0)
    with pytest.raises(DataError, match="in mm") as error:
        read_sequence("csv", path, **CSV_KEYS, gt_pos=GT_KEYS["gt_pos"], gt_quat=GT_KEYS["gt_quat"])
    assert error.value.field == "gt.pos"


# ---- graphs that cannot be solved are named, not solved to an arbitrary answer ------------------------------------


def test_too_few_or_too_close_fixes_without_a_first_state(flight):
    from airimu.fuse import fuse
    from airimu_core.sequence import GpsFixes

    blind = flight.part(0.0, 1.0)
    gps = flight.gps
    for rows, sigma in ((slice(0, 2), 0.1), (slice(0, 3), 1.0)):  # two fixes; three within 5 sigmas
        close = GpsFixes(gps.t[rows], gps.pos[rows], np.full_like(gps.pos[rows], sigma))
        with pytest.raises(GraphError, match="under-constrained"):
            fuse(blind, close)


def test_a_pgo_rate_that_leaves_one_fix_names_the_option(flight, tmp_path):
    from airimu.experiments.pgo import PgoOptions, run_sequence
    from learned_imu.network.model import Correction

    gyro, acc = torch.as_tensor(flight.gyro), torch.as_tensor(flight.acc)
    zero = torch.zeros_like(gyro)
    correction = Correction(gyro, acc, zero, zero, torch.full_like(gyro, 1e-6), torch.full_like(acc, 1e-4))
    with pytest.raises(ConfigError, match="options.gps_hz: at 0.02 Hz .* gets 1 GPS fix"):
        run_sequence(flight, correction, tmp_path, PgoOptions(gps_hz=(0.02,), seeds=1))


# ---- checkpoints, outputs, sizes, temporaries -----------------------------------------------------------------------


def test_a_checkpoint_with_nan_weights_is_named(tmp_path, capsys, monkeypatch):
    config = ModelConfig(conv_channels=(8, 16), gru_sizes=(16,), decoder_hidden=16)
    model = build_model(config)
    state = model.state_dict()
    name = next(k for k, v in state.items() if v.is_floating_point())
    state[name].view(-1)[0] = float("nan")
    path = write_checkpoint(tmp_path / "nan.pt", config, state)
    with pytest.raises(DataError, match=f"trainer.model.{name}.*NaN or Inf weights"):
        model_from_checkpoint(path)
    code, err = cli(
        capsys, monkeypatch, "export-model", "--checkpoint", path, "--format", "torchscript", "--out", tmp_path / "m.pt"
    )
    assert code == 2 and "NaN or Inf weights" in err and not (tmp_path / "m.pt").exists()


def test_output_paths_of_the_wrong_kind(tmp_path):
    (tmp_path / "dir.json").mkdir()
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="dir.json: is a folder"):
        write_json_atomic(tmp_path / "dir.json", {})
    with pytest.raises(InputError, match="is a file"):
        output_folder(tmp_path / "file" / "run")
    with pytest.raises(InputError, match="a part of .* is a file"):
        write_json_atomic(tmp_path / "file" / "out.json", {})


def test_inputs_far_beyond_any_imu_log_are_refused(files, monkeypatch):
    monkeypatch.setenv("AIRIMU_MAX_INPUT_BYTES", "1000")
    with pytest.raises(DataError, match="AIRIMU_MAX_INPUT_BYTES") as error:
        read_sequence("csv", files / "imu_only.csv", **CSV_KEYS)
    assert "imu_only.csv" in str(error.value)
    monkeypatch.setenv("AIRIMU_MAX_INPUT_BYTES", str(10**9))
    assert len(read_sequence("csv", files / "imu_only.csv", **CSV_KEYS)) == 3000


def test_a_killed_writers_temporary_is_removed_by_the_next_write(tmp_path):
    target = tmp_path / "seq.npz"
    dead = tmp_path / ".seq.npz.999999999.abc123.tmp"  # no such process
    alive = tmp_path / f".seq.npz.{os.getpid()}.def456.tmp"  # a writer still running: kept
    dead.write_bytes(b"half")
    alive.write_bytes(b"half")
    with atomic_file(target, "wb") as f:
        f.write(b"whole")
    assert target.read_bytes() == b"whole" and not dead.exists() and alive.exists()


def test_a_remove_gravity_model_on_data_without_ground_truth(flight):
    import dataclasses

    from learned_imu.network.inference import correct

    model = build_model(ModelConfig(conv_channels=(8, 16), gru_sizes=(16,), decoder_hidden=16)).eval()
    blind = dataclasses.replace(flight, gt=None)
    with pytest.raises(InputError, match="removes gravity with ground truth; the sequence has none"):
        correct(model, blind, remove_gravity=True)
    assert correct(model, blind).gyro.shape == flight.gyro.shape  # the same model without it runs


LITERAL_CASES = {
    "train.device": ("train: {device: gpu}", "expected one of cpu, cuda, auto"),
    "evaluation.interval_unit": ("evaluation: {interval_unit: minutes}", "expected one of s, frames"),
}


@pytest.mark.parametrize("key", sorted(LITERAL_CASES))
def test_fixed_choices_in_configs_are_literal_types(key, tmp_path):
    """Config fields with a fixed set of values are typed ``Literal[...]``: the loader names the key and the set."""
    body, message = LITERAL_CASES[key]
    text = f"name: x\ndata: {{train: [{{dataset: simulator}}], val: [{{dataset: simulator}}]}}\n{body}\n"
    refused_config(tmp_path, text, rf"key '{key}': {message}")


def test_pgo_and_fusion_choices_are_literal_types(tmp_path):
    from airimu.experiments.pgo_config import load_pgo_config

    for block, key, message in (
        ("options: {gps_source: radio}", "options.gps_source", "auto, simulated, recorded"),
        ("fusion: {backend: ceres}", "fusion.backend", "gtsam, custom"),
    ):
        path = tmp_path / "pgo.yaml"
        path.write_text(f"name: p\nexperiment: demo.yaml\nrun: r\n{block}\n")
        with pytest.raises(ConfigError, match=rf"key '{key}': expected one of {message}"):
            load_pgo_config(path)

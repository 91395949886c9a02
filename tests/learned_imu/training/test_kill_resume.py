"""Crash safety: ``airimu train`` killed with SIGKILL resumes from its last checkpoint, losing at most the epoch in
progress, with a clean metrics log and no temporary file left; an export killed mid-write leaves the previous file
at its path intact (or no file), never a truncated one.

The kills are real SIGKILLs of real processes (no clean-up code runs). Besides a kill at a seeded random moment,
two worst moments are hit on purpose by a hook inside the child process: between the two files an epoch writes
(metrics log and ``last.pt``), and in the middle of writing ``last.pt``."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from airimu_core.errors import DataError
from factors import load_export
from learned_imu.datasets.simulator import ImuErrorModel, simulate
from learned_imu.export import export_preintegration, keyframes_every
from learned_imu.network.checkpoint import load_checkpoint

pytestmark = pytest.mark.slow  # real processes: training runs and SIGKILLs

AIRIMU = str(Path(sys.executable).with_name("airimu"))
EPOCHS = 6
CONFIG_YAML = f"""
name: kill-resume
data:
  train: [{{dataset: simulator, options: {{duration_s: 10.0, seed: 1, device_seed: 5}}}}]
  val: [{{dataset: simulator, options: {{duration_s: 5.0, seed: 2, device_seed: 5}}}}]
model: {{conv_channels: [8, 16], gru_sizes: [16], decoder_hidden: 16}}
train: {{window: 200, every: 50, batch_size: 4, epochs: {EPOCHS}, lr: 3e-3, calibration_steps: 10}}
"""
RUN_FILES = [".lock", "best.pt", "config.yaml", "last.pt", "metrics.jsonl", "training.rrd"]  # .lock: the writer lock
# (free now); training.rrd: the CLI's Rerun recording of the metrics
TIMEOUT_S = 600  # generous: the machine is shared; a run takes ~20 s alone
WHITE = ImuErrorModel(1e-4, 1e-3, 0.0, 0.0, 0.0, 0.0)


def train_command(tmp_path: Path) -> list[str]:
    config = tmp_path / "config.yaml"
    config.write_text(CONFIG_YAML)
    return [AIRIMU, "train", "--config", str(config), "--out", str(tmp_path / "run"), "--no-progress"]


def metrics(run: Path) -> list[dict]:
    """The metrics log, every line parsed (a garbled line fails here)."""
    path = run / "metrics.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def wait_for(condition, proc: subprocess.Popen, what: str) -> None:
    deadline = time.monotonic() + TIMEOUT_S
    while not condition():
        assert proc.poll() is None, f"the process ended (code {proc.returncode}) before {what}"
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.01)


def resume_and_check(cmd: list[str], run: Path, before: list[dict], done: int) -> None:
    """Run the same command again to the end; the run must continue after epoch ``done`` and end clean."""
    subprocess.run(cmd, check=True, timeout=TIMEOUT_S, capture_output=True)
    after = metrics(run)
    assert [e["epoch"] for e in after] == list(range(EPOCHS))  # no lost, duplicated or garbled line
    assert after[:done] == before[:done]  # the checkpointed epochs were kept as logged, not trained again
    assert np.all(np.diff([e["seconds"] for e in after]) > 0)  # time continues across the kill
    assert load_checkpoint(run / "last.pt").trainer["epochs_done"] == EPOCHS
    best = load_checkpoint(run / "best.pt").best
    assert best.calibrated and best.val_loss == min(e["val_loss"] for e in after)
    assert sorted(p.name for p in run.iterdir()) == RUN_FILES  # no temporary file left behind


def test_sigkill_at_a_random_moment_resumes_from_the_last_checkpoint(tmp_path):
    cmd, run = train_command(tmp_path), tmp_path / "run"
    rng = np.random.default_rng(2024)
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_for(lambda: len(metrics(run)) >= 2, proc, "two epochs")
        first = metrics(run)
        epoch_s = first[1]["seconds"] - first[0]["seconds"]  # 0.1 s on an idle machine, seconds on a busy one
        time.sleep(rng.uniform(0.0, 1.0) * epoch_s)  # a random moment of the next epoch
        assert proc.poll() is None  # still training: the kill lands mid-run
    finally:
        proc.kill()  # SIGKILL
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    before = metrics(run)
    done = load_checkpoint(run / "last.pt").trainer["epochs_done"]
    completed = max(len(before), done)  # epochs finished before the kill, by any file's account
    assert completed >= 2 and done >= completed - 1  # the checkpoint lost at most one of them
    load_checkpoint(run / "best.pt")
    resume_and_check(cmd, run, before, done)


# Child process: training with a hook that SIGKILLs itself at a chosen moment of epoch KILL_EPOCH's writes.
KILL_HOOK = """
import io, os, signal, sys
import torch
import learned_imu.training.experiment as experiment
from airimu.cli import main

MOMENT, KILL_EPOCH = sys.argv[1], int(sys.argv[2])
real_save, real_metrics, real_torch_save = experiment.save_checkpoint, experiment._write_metrics, torch.save
writing = None  # the checkpoint being saved

def die():
    os.kill(os.getpid(), signal.SIGKILL)

def save_checkpoint(path, checkpoint):  # between the writes: after the epoch's first
    global writing
    writing = path.name
    out = real_save(path, checkpoint)
    epochs_done = checkpoint.trainer["epochs_done"]
    if MOMENT == "between_writes" and path.name == "last.pt" and epochs_done == KILL_EPOCH + 1:
        die()
    if MOMENT == "after_calibrated_best" and path.name == "best.pt" and checkpoint.best.calibrated:
        die()  # the calibrated best.pt is on disk, last.pt does not know yet
    return out

def write_metrics(path, history):
    real_metrics(path, history)
    if MOMENT == "between_writes" and len(history) == KILL_EPOCH + 1:
        die()

def torch_save(obj, f, *args, **kwargs):  # mid-write: half of last.pt's bytes reach its temporary file
    epoch_last = isinstance(obj, dict) and obj.get("trainer", {}).get("epochs_done") == KILL_EPOCH + 1
    if MOMENT == "mid_checkpoint_write" and epoch_last and writing == "last.pt":
        buffer = io.BytesIO()
        real_torch_save(obj, buffer, *args, **kwargs)
        f.write(buffer.getvalue()[: len(buffer.getvalue()) // 2])
        f.flush()
        die()
    return real_torch_save(obj, f, *args, **kwargs)

experiment.save_checkpoint, experiment._write_metrics, torch.save = save_checkpoint, write_metrics, torch_save
sys.argv = ["airimu", *sys.argv[3:]]
main()
"""


@pytest.mark.parametrize("moment", ["between_writes", "mid_checkpoint_write"])
def test_sigkill_at_the_worst_moments_of_an_epochs_writes(tmp_path, moment):
    """``between_writes``: the epoch's first file is written, the second not (whichever order the loop uses);
    ``mid_checkpoint_write``: ``last.pt`` half written. Either way the resumed run must not skip, repeat or garble
    an epoch, and must not leave the half-written temporary behind."""
    cmd, run = train_command(tmp_path), tmp_path / "run"
    kill_epoch = 2
    proc = subprocess.run(
        [sys.executable, "-c", KILL_HOOK, moment, str(kill_epoch), *cmd[1:]], capture_output=True, timeout=TIMEOUT_S
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr.decode()[-2000:]
    before = metrics(run)
    done = load_checkpoint(run / "last.pt").trainer["epochs_done"]
    assert done in (kill_epoch, kill_epoch + 1) and len(before) in (kill_epoch, kill_epoch + 1)
    if moment == "mid_checkpoint_write":
        (partial,) = run.glob(".last.pt.*.tmp")  # what the kill left: a truncated temporary file
        assert done == kill_epoch  # and last.pt still holds the previous epoch, readable
        with pytest.raises(DataError, match="not a readable torch checkpoint"):
            load_checkpoint(partial)
    resume_and_check(cmd, run, before, done)


def test_sigkill_after_the_calibrated_best_checkpoint_does_not_calibrate_twice(tmp_path):
    """Killed after the calibrated ``best.pt`` is written and before ``last.pt`` records it: the resumed run takes
    the calibration from ``best.pt`` (weights unchanged) and only brings ``last.pt`` up to date."""
    import torch

    cmd, run = train_command(tmp_path), tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-c", KILL_HOOK, "after_calibrated_best", "0", *cmd[1:]],
        capture_output=True,
        timeout=TIMEOUT_S,
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr.decode()[-2000:]
    calibrated = load_checkpoint(run / "best.pt")
    assert calibrated.best.calibrated and not load_checkpoint(run / "last.pt").best.calibrated
    subprocess.run(cmd, check=True, timeout=TIMEOUT_S, capture_output=True)
    after = load_checkpoint(run / "best.pt")
    assert after.best == calibrated.best
    for name, tensor in calibrated.trainer["model"].items():
        assert torch.equal(after.trainer["model"][name], tensor), name  # not calibrated a second time
    assert load_checkpoint(run / "last.pt").best == calibrated.best


# Child process: an export written to a slow device (every write paced at 4 MB/s), killed by the parent mid-write.
SLOW_EXPORT = """
import contextlib, sys, time
import airimu_core.io
import learned_imu.export as export
from learned_imu.datasets.simulator import ImuErrorModel, simulate

class SlowFile:
    def __init__(self, f):
        self._f = f
    def write(self, data):
        time.sleep(len(data) / 4e6 + 0.002)
        return self._f.write(data)
    def __getattr__(self, name):
        return getattr(self._f, name)

real_atomic_file = airimu_core.io.atomic_file  # what airimu_core.export.save_export writes through

@contextlib.contextmanager
def slow_atomic_file(path, mode="w"):
    with real_atomic_file(path, mode) as f:
        yield SlowFile(f)

airimu_core.io.atomic_file = slow_atomic_file
seq = simulate("drone", duration_s=60.0, error_model=ImuErrorModel(1e-4, 1e-3, 0.0, 0.0, 0.0, 0.0), seed=9)
export.export_preintegration(sys.argv[1], seq, export.keyframes_every(seq, 0.1), 1e-8, 1e-6)
"""


@pytest.mark.parametrize("previous", [True, False])
def test_export_killed_mid_write_leaves_the_previous_file_or_none(tmp_path, previous):
    path = tmp_path / "seq.npz"
    seq = simulate("drone", duration_s=20.0, error_model=WHITE, seed=1)
    if previous:
        export_preintegration(path, seq, keyframes_every(seq, 0.1), 1e-8, 1e-6)
        old = path.read_bytes()
    rng = np.random.default_rng(7 + previous)
    proc = subprocess.Popen([sys.executable, "-c", SLOW_EXPORT, str(path)], stderr=subprocess.PIPE)
    try:
        wait_for(lambda: any(tmp_path.glob(".seq.npz.*.tmp")), proc, "the export's temporary file")
        time.sleep(rng.uniform(0.05, 0.5))  # the paced write of ~3.4 MB takes ~1 s
        assert proc.poll() is None  # still writing
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    (partial,) = tmp_path.glob(".seq.npz.*.tmp")
    assert partial.stat().st_size > 0  # the kill landed mid-write: a started, unfinished file
    with pytest.raises((zipfile.BadZipFile, ValueError, EOFError, OSError)):
        np.load(partial)
    if previous:
        assert path.read_bytes() == old  # the previous export, byte for byte
        np.testing.assert_array_equal(load_export(path).keyframe_t, seq.t[keyframes_every(seq, 0.1)])
    else:
        assert not path.exists()

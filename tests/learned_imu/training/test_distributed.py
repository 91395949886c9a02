"""Training under ``torchrun``: two processes give the one-process run with the same global batch.

Not bitwise: the two runs add the same numbers in other orders (the global batch's mean loss is the mean of two
shard means, DDP sums the two shards' gradients, the synchronised BatchNorm sums its statistics in float64 where
``BatchNorm1d`` uses its own kernel, and the processes run one thread each). Float32 round-off of ~1e-7 is what
remains, and Adam keeps it small: measured 4e-8 to 7e-8 relative on the losses and 5e-7 to 1e-6 absolute on
the weights after two or three epochs (Adam steps are 3e-3), so the tolerances below are 1e-5 relative on losses
and metrics and 1e-5 absolute on weights. The random states (shuffling, dropout) must be equal exactly: every
rank draws the global batch's order and dropout mask.

The two-process run resumes a run that one process started (one launch, to keep the test short: it checks that
every rank loads ``last.pt``, and that checkpoints do not depend on the number of processes), then trains two
epochs. It has 9 training windows in batches of 4, so the last batch of each epoch is 1 window: rank 1 trains on
no window there, which must still give the one-process step."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from airimu_core.errors import ConfigError
from learned_imu.config import load_config
from learned_imu.network.checkpoint import load_checkpoint
from learned_imu.training.distributed import World, check_batch_size, shard, world_from_env
from learned_imu.training.experiment import RUN_FILES, train_run, with_epochs

pytestmark = pytest.mark.slow  # real processes: a torchrun-style process group training

EPOCHS = 3  # one in one process, then two in two processes
CONFIG_YAML = f"""
name: distributed
data:
  train: [{{dataset: simulator, options: {{duration_s: 10.0, seed: 1, device_seed: 5}}}}]
  val: [{{dataset: simulator, options: {{duration_s: 5.0, seed: 2, device_seed: 5}}}}]
model: {{conv_channels: [8, 16], gru_sizes: [16], decoder_hidden: 16}}
train: {{window: 200, every: 50, batch_size: 4, epochs: {EPOCHS}, lr: 3e-3, calibration_steps: 5}}
"""
LOSS_RTOL = 1e-5
WEIGHT_ATOL = 1e-5
TIMEOUT_S = 300  # generous: the machine is shared; the launch takes ~20 s here


def metrics(run: Path) -> list[dict]:
    return [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]


def torchrun_train(config: Path, out: Path, epochs: int) -> subprocess.CompletedProcess:
    """``airimu train`` in two processes, as the README launches it."""
    launch = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2"]
    train = ["-m", "airimu.cli", "train", "--config", str(config), "--out", str(out), "--epochs", str(epochs)]
    return subprocess.run([*launch, *train, "--no-progress"], capture_output=True, text=True, timeout=TIMEOUT_S)


def test_two_processes_give_the_one_process_loss_curve_and_write_one_run_folder(tmp_path):
    config = tmp_path / "config.yaml"
    config.write_text(CONFIG_YAML)
    single, multi = tmp_path / "single", tmp_path / "multi"
    train_run(load_config(config), single, progress=False)
    train_run(with_epochs(load_config(config), 1), multi, progress=False)  # epoch 0 in one process
    proc = torchrun_train(config, multi, EPOCHS)  # resumes: every rank loads last.pt
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.count("run folder:") == 1  # one summary: rank 0's
    written = [*RUN_FILES, ".lock", "training.rrd"]  # training.rrd: the CLI's recording, rank 0's
    assert sorted(p.name for p in multi.iterdir()) == sorted(written)  # one set of files, no temporaries

    one, two = metrics(single), metrics(multi)
    assert two[0] == one[0] | {"seconds": two[0]["seconds"]}  # the one-process epoch, kept as logged
    assert [e["epoch"] for e in two] == list(range(EPOCHS))
    assert [e["lr"] for e in two] == [e["lr"] for e in one]
    for key in ("train_loss", "val_loss", "val_roe_deg", "val_rpe_rmse_m"):
        assert [e[key] for e in two] == pytest.approx([e[key] for e in one], rel=LOSS_RTOL), key
    assert one[-1]["train_loss"] < 0.9 * one[0]["train_loss"]  # it trained: a real curve to compare

    for name in ("last.pt", "best.pt"):
        a, b = load_checkpoint(single / name), load_checkpoint(multi / name)
        assert b.best.epoch == a.best.epoch and b.best.calibrated
        assert a.trainer["model"].keys() == b.trainer["model"].keys()  # plain keys: no DDP "module." prefix
        for key, weight in a.trainer["model"].items():
            torch.testing.assert_close(b.trainer["model"][key], weight, rtol=0, atol=WEIGHT_ATOL, msg=key)
        assert torch.equal(a.trainer["generator"], b.trainer["generator"])  # same shuffling
        assert torch.equal(a.trainer["torch_rng"], b.trainer["torch_rng"])  # same dropout draws


def test_a_batch_that_does_not_split_evenly_is_a_config_error(tmp_path):
    config = tmp_path / "config.yaml"
    config.write_text(CONFIG_YAML.replace("batch_size: 4", "batch_size: 3"))
    with pytest.raises(ConfigError, match=r"train\.batch_size.*3 windows do not split into 2 equal shards"):
        train_run(load_config(config), tmp_path / "run", progress=False, world=World(rank=0, size=2))
    assert not (tmp_path / "run").exists()  # refused before anything was written
    check_batch_size(3, None)  # one process: any batch size


def test_shards_partition_each_global_batch_and_weight_its_mean():
    assert world_from_env({}) is None and world_from_env({"WORLD_SIZE": "1", "RANK": "0"}) is None
    assert world_from_env({"WORLD_SIZE": "4", "RANK": "3", "LOCAL_RANK": "1"}) == World(3, 4, 1)
    losses = torch.rand(7, generator=torch.Generator().manual_seed(0))  # per-window losses of a global batch
    for size in (7, 4, 3, 2):  # a full batch, and last batches of 3 and 2 windows (rank 2 and 3 get none)
        batch = torch.arange(10, 10 + size)
        parts = [shard(batch, World(rank, 4)) for rank in range(4)]
        assert torch.equal(torch.cat([index for index, _ in parts]), batch)  # in order, each window once
        # DDP averages the ranks' gradients of scale * (shard mean): the same weights as the global mean
        shard_means = [losses[index - 10].mean() if len(index) else 0.0 for index, _ in parts]
        averaged = sum(scale * mean for (_, scale), mean in zip(parts, shard_means, strict=True)) / 4
        assert float(averaged) == pytest.approx(float(losses[:size].mean()), rel=1e-6)
    assert shard(batch, None) == (batch, 1.0)


def test_chunk_shards_are_weighted_by_the_windows_they_hold():
    """Chunks hold different numbers of valid windows: each rank's loss, a mean over its chunks' windows, scaled by
    ``shard``, averages to the mean over every window of the global batch."""
    g = torch.Generator().manual_seed(1)
    counts = torch.tensor([201, 120, 201, 0, 186, 201, 57])  # valid windows of each chunk (one with none)
    losses = [torch.rand(int(n), generator=g, dtype=torch.float64) for n in counts]  # per-window losses
    for size in (7, 5, 3):
        batch = torch.arange(size)
        parts = [shard(batch, World(rank, 3), counts) for rank in range(3)]
        means = [torch.cat([losses[i] for i in index]).mean() if counts[index].sum() else 0.0 for index, _ in parts]
        averaged = sum(scale * mean for (_, scale), mean in zip(parts, means, strict=True)) / 3
        assert float(averaged) == pytest.approx(float(torch.cat(losses[:size]).mean()), rel=1e-12)

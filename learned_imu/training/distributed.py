"""Training on several processes or machines (``torchrun``): every rank trains on its shard of each global batch.

``torchrun`` starts one process per rank and sets ``RANK``, ``WORLD_SIZE`` and ``LOCAL_RANK``; ``process_group()``
reads them and initialises ``torch.distributed`` (gloo on CPU, nccl for a CUDA device), or yields ``None`` in one
process, where nothing here is used. With the same seed the run equals the one-process run with the same global
batch (``train.batch_size``), up to float round-off:

- every rank draws the same shuffled order, and takes a contiguous part of each global batch (``shard``); the
  loss, a mean over windows, is scaled by ``windows here * world size / windows in the batch``, so DDP's average
  of the ranks' gradients is the gradient of the global batch's mean (a last, partial batch may leave a rank
  with fewer windows, even none: an empty batch gives zero gradients);
- BatchNorm normalises with the global batch's statistics (``SyncBatchNorm1d``: ``torch.nn.SyncBatchNorm``
  refuses CPU tensors, checked in torch 2.13, so gloo training needs this one), and dropout draws the global
  batch's mask from the torch RNG, which stays identical on every rank, and keeps this rank's rows
  (``ShardedDropout``);
- rank 0 alone validates and writes; decisions that depend on validation (LR schedule, best epoch, early stop)
  use the value it broadcasts (``from_writer``).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import torch
import torch.distributed as dist
from torch import nn

from airimu_core.errors import ConfigError


@dataclass(frozen=True)
class World:
    """This process's place in a ``torchrun`` job: global ``rank`` of ``size`` ranks, ``local_rank`` on its node."""

    rank: int
    size: int
    local_rank: int = 0

    @property
    def writer(self) -> bool:
        """Rank 0 writes the run folder, logs progress and validates."""
        return self.rank == 0


def world_from_env(environ: dict[str, str] | None = None) -> World | None:
    """The ``World`` that ``torchrun``'s variables describe, or None when ``WORLD_SIZE`` is unset or 1."""
    env = os.environ if environ is None else environ
    size = int(env.get("WORLD_SIZE", "1"))
    if size <= 1:
        return None
    return World(int(env["RANK"]), size, int(env.get("LOCAL_RANK", "0")))


def is_writer(world: World | None) -> bool:
    return world is None or world.writer


@contextmanager
def process_group(device: str = "cpu") -> Iterator[World | None]:
    """Initialise ``torch.distributed`` from ``torchrun``'s environment for the duration of the block (yields
    None in one process). Backend: nccl for a CUDA ``device`` (one GPU per local rank), else gloo."""
    world = world_from_env()
    if world is None:
        yield None
        return
    backend = "nccl" if torch.device(device).type == "cuda" else "gloo"
    if backend == "nccl":
        torch.cuda.set_device(world.local_rank)
    dist.init_process_group(backend, rank=world.rank, world_size=world.size)
    try:
        yield world
    finally:
        dist.destroy_process_group()


def check_batch_size(batch_size: int, world: World | None) -> None:
    """The global batch must split into equal shards: a ``ConfigError`` naming ``train.batch_size`` otherwise."""
    if world is not None and batch_size % world.size != 0:
        raise ConfigError(
            f"key 'train.batch_size': {batch_size} windows do not split into {world.size} equal shards "
            f"(one per rank); use a multiple of {world.size}"
        )


def shard(batch: torch.Tensor, world: World | None, windows: torch.Tensor | None = None) -> tuple[torch.Tensor, float]:
    """This rank's contiguous part of a global batch of window (or chunk) indices, and its loss scale
    ``n_here * world size / n_batch`` (1 for equal parts; 0 for an empty part), with ``n`` counted in windows when
    ``windows`` gives each item's count (chunks hold different numbers of valid windows). In one process: all of
    it, 1."""
    if world is None:
        return batch, 1.0
    part = torch.tensor_split(batch, world.size)[world.rank]
    if windows is None:
        return part, len(part) * world.size / len(batch)
    total = float(windows[batch].sum())
    return part, float(windows[part].sum()) * world.size / total if total else 0.0


def global_loss(loss: float, scale: float, world: World | None) -> float:
    """The global batch's mean loss from every rank's mean over its shard and ``shard``'s scale."""
    if world is None:
        return loss
    total = torch.tensor(loss * scale / world.size if scale else 0.0, dtype=torch.float64)
    dist.all_reduce(total)
    return float(total)


def from_writer(compute: Callable[[], float], world: World | None) -> float:
    """``compute()`` on rank 0, broadcast to every rank (the others wait)."""
    if world is None:
        return compute()
    value = torch.tensor(compute() if world.writer else math.nan, dtype=torch.float64)
    dist.broadcast(value, src=0)
    return float(value)


def agree(value: float, world: World | None) -> bool:
    """Whether every rank holds rank 0's ``value`` (the same answer on every rank)."""
    if world is None:
        return True
    same = torch.tensor(int(from_writer(lambda: value, world) == value))
    dist.all_reduce(same, op=dist.ReduceOp.MIN)
    return bool(same)


def barrier(world: World | None) -> None:
    if world is not None:
        dist.barrier()


def wrap(model: nn.Module, world: World, unused: tuple[str, ...] = ()) -> nn.Module:
    """``model`` with synchronised BatchNorm and sharded dropout (in place: same parameters and buffers, same
    state-dict keys), wrapped in ``DistributedDataParallel`` (call the wrapper to train, save ``model``).

    ``unused``: parameters (by name part) that the loss never reaches, such as the noise decoders without the
    covariance loss. They stop requiring gradients, so DDP does not wait for them and, as in one process, their
    gradient stays None and the optimiser leaves them alone (DDP's ``find_unused_parameters`` cannot see that
    the unused outputs are returned; ``static_graph=True`` gave wrong gradients here, torch 2.13 with gloo)."""
    for name, parameter in model.named_parameters():
        if any(part in name for part in unused):
            parameter.requires_grad_(False)
    _replace(model, dist.new_group())  # a group of their own: never interleaved with DDP's gradient all-reduces
    return nn.parallel.DistributedDataParallel(model)


class _AllReduceSum(torch.autograd.Function):
    """Sum over ranks. Every rank's loss depends on the sum, so the gradient reaching each rank's input is the
    sum of the ranks' gradients of the output (as in ``torch.nn.SyncBatchNorm``'s backward)."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, group) -> torch.Tensor:
        ctx.group = group
        x = x.clone()
        dist.all_reduce(x, group=group)
        return x

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> tuple[torch.Tensor, None]:
        grad = grad.clone()
        dist.all_reduce(grad, group=ctx.group)
        return grad, None


class SyncBatchNorm1d(nn.BatchNorm1d):
    """``BatchNorm1d`` whose training-mode statistics are the global batch's: per-channel sums of x and x^2 and
    the count, all-reduced (float64 sums, so that ``E[x^2] - E[x]^2`` loses nothing in float32 terms), with
    gradients through the all-reduce over ``group`` (None: all ranks). Evaluation mode is ``BatchNorm1d``'s.
    Input (B, C) or (B, C, L)."""

    group = None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not (self.training and dist.is_initialized()):
            return super().forward(x)
        dims = [0, *range(2, x.ndim)]
        channels = x.shape[1]
        wide = x.double()
        count = torch.tensor([x.numel() / channels], dtype=torch.float64)
        sums = _AllReduceSum.apply(torch.cat([wide.sum(dims), wide.square().sum(dims), count]), self.group)
        n = sums[-1].detach()
        mean = sums[:channels] / n
        var = sums[channels : 2 * channels] / n - mean.square()  # biased, as BatchNorm normalises
        if self.track_running_stats:
            self._update_running_stats(mean.detach(), var.detach() * n / (n - 1))
        shape = (1, channels) + (1,) * (x.ndim - 2)
        out = (x - mean.to(x.dtype).view(shape)) * torch.rsqrt(var + self.eps).to(x.dtype).view(shape)
        return out * self.weight.view(shape) + self.bias.view(shape) if self.affine else out

    @torch.no_grad()
    def _update_running_stats(self, mean: torch.Tensor, unbiased_var: torch.Tensor) -> None:
        self.num_batches_tracked.add_(1)
        factor = self.momentum if self.momentum is not None else 1.0 / float(self.num_batches_tracked)
        self.running_mean.lerp_(mean.to(self.running_mean.dtype), factor)
        self.running_var.lerp_(unbiased_var.to(self.running_var.dtype), factor)


class ShardedDropout(nn.Dropout):
    """Dropout whose training-mode mask is the global batch's (drawn as ``nn.Dropout`` draws it, from the torch RNG,
    which therefore advances alike on every rank), cut to this rank's rows. Shards are contiguous in rank order
    (``shard``); their sizes are all-reduced over ``group``. Evaluation mode and ``p = 0`` are ``nn.Dropout``'s."""

    group = None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not (self.training and self.p > 0 and dist.is_initialized()):
            return super().forward(x)
        rank = dist.get_rank(self.group)
        sizes = torch.zeros(dist.get_world_size(self.group), dtype=torch.int64)
        sizes[rank] = x.shape[0]
        dist.all_reduce(sizes, group=self.group)
        first = int(sizes[:rank].sum())
        mask = x.new_empty((int(sizes.sum()), *x.shape[1:])).bernoulli_(1 - self.p)[first : first + x.shape[0]]
        return x * mask * (0.0 if self.p == 1 else 1 / (1 - self.p))


def _replace(module: nn.Module, group) -> None:
    """Swap every ``BatchNorm1d`` and ``Dropout`` below ``module`` for the synchronised kind over ``group``, keeping
    the tensors."""
    for name, child in module.named_children():
        if type(child) is nn.BatchNorm1d:
            c = child
            new = SyncBatchNorm1d(c.num_features, c.eps, c.momentum, c.affine, c.track_running_stats)
            for key, value in [*child.named_parameters(recurse=False), *child.named_buffers(recurse=False)]:
                setattr(new, key, value)
        elif type(child) is nn.Dropout:
            new = ShardedDropout(child.p, child.inplace)
        else:
            _replace(child, group)
            continue
        new.group = group
        setattr(module, name, new.train(child.training))

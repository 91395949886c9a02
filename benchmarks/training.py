"""One training epoch on EuRoC: the per-window trainer against the every-window trainer (chunks), side by side.

    python benchmarks/training.py [--data ../shared/data] [--per-window-steps 10] [--every-window-epochs 1]
        [--batch-sizes 16,128] [--chunk 3000] [--chunk-batch 1] [--flights MH_01_easy,...] [--threads 2]
        [--memory] [--json FILE]

The official AirIMU schedule on the six EuRoC training flights (MH_01_easy, MH_03_medium, MH_05_difficult,
V1_02_medium, V2_01_easy, V2_03_difficult, full length): windows of W = 1000 samples starting at every s = 10th
sample, supervised at every k = 50th, 18 samples of network context. Both trainers train the same seeded
``AirImuNet()`` (defaults) on the same windows with the same loss (``LossWeights()`` with the covariance NLL) and
Adam (lr 1e-3, the trainer's weight decay 1e-4); each training step is ``Trainer.epoch``'s: select the batch,
``window_loss``, zero_grad, backward, optimiser step, ``loss.item()``.

- per-window (``train.chunk: 0``): ``make_windows(seq, 1000, 50, 10, context=18)`` of every flight, concatenated;
  shuffled batches of B windows, each window corrected and integrated on its own, for each B of ``--batch-sizes``
  (16: configs/euroc.yaml's batch; 128: the official one). A full epoch takes minutes, so only
  ``--per-window-steps`` steps are timed (after ``--warmup`` steps) and the epoch time is extrapolated from them.
- every-window (``train.chunk``): ``make_chunks(seq, --chunk, 1000, 50, 10, context=18)``, concatenated; real full
  epochs (``--every-window-epochs``) of ``Trainer(model, chunks, val, batch_size=--chunk-batch)``'s training loop,
  timed without the validation (measured on its own: ``Trainer.validation_loss`` on the same six flights in chunks
  with windows every 200 samples, the official "test" loader). Warm-up steps run on a throwaway trainer first.

Windows per second counts supervised windows: B a step on the per-window side, the chunks' valid windows
(``Chunks.windows``) on the every-window side; both sides hold the same windows (checked, and printed). The
official schedule's time is 100 epochs of the every-window trainer, with and without the validation.

``--memory``: the peak RSS of one training step (every-window, at ``--chunk-batch`` chunks; per-window at each B for
comparison), each in a fresh process that reads only the flight(s) it needs, started before this process loads any
data. ``ru_maxrss`` is the whole process's peak (imports, reading the flight, the step); "step" is how far the step
itself rises above the resident size before it (``VmHWM`` after resetting it, Linux).
"""

from __future__ import annotations

import argparse
import datetime
import gc
import json
import math
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import torch

from airimu_core.io import atomic_file
from learned_imu.datasets import read_sequence
from learned_imu.network.model import AirImuNet
from learned_imu.training.chunks import concat_chunks, make_chunks
from learned_imu.training.losses import LossWeights
from learned_imu.training.train import Trainer, TrainingData, window_loss
from learned_imu.training.windows import concat_windows, make_windows

FLIGHTS = ("MH_01_easy", "MH_03_medium", "MH_05_difficult", "V1_02_medium", "V2_01_easy", "V2_03_difficult")
WINDOW, EVERY, STRIDE, CONTEXT = 1000, 50, 10, 18  # the official AirIMU schedule (configs/euroc_official.yaml)
VAL_STRIDE = 200  # the official "test" loader: the training flights, a window every 200 samples
LR = 1e-3
SCHEDULE_EPOCHS = 100  # the official schedule
EVERY_WINDOW = "every-window"
PER_WINDOW = "per-window"


def read_flights(data: Path, names) -> list:
    return [read_sequence("euroc", data / "euroc" / name) for name in names]


def per_window_data(sequences, stride: int = STRIDE) -> TrainingData:
    return concat_windows([make_windows(s, WINDOW, EVERY, stride, context=CONTEXT) for s in sequences])


def every_window_data(sequences, chunk: int, stride: int = STRIDE) -> TrainingData:
    return concat_chunks([make_chunks(s, chunk, WINDOW, EVERY, stride, context=CONTEXT) for s in sequences])


def new_trainer(train: TrainingData, val: TrainingData, batch_size: int, seed: int) -> Trainer:
    """A trainer of a freshly seeded ``AirImuNet()`` (the same initial weights every time)."""
    torch.manual_seed(seed)
    return Trainer(AirImuNet(), train, val, batch_size=batch_size, lr=LR, weights=LossWeights(), seed=seed)


def train_steps(trainer: Trainer, steps: int | None = None) -> list[tuple[int, float]]:
    """``Trainer.epoch``'s training loop (one process: no sharding), without its validation and LR schedule: one
    shuffled pass, or its first ``steps`` batches. Returns (supervised windows, seconds) of each step."""
    trainer.model.train()
    order = torch.randperm(len(trainer.train), generator=trainer.generator)
    records = []
    for first in range(0, len(trainer.train), trainer.batch_size):
        if steps is not None and len(records) == steps:
            break
        start = time.perf_counter()
        batch = trainer.train.select(order[first : first + trainer.batch_size])
        loss = window_loss(trainer.net, batch, trainer.weights, trainer.use_covariance)
        trainer.optimiser.zero_grad()
        loss.backward()
        trainer.optimiser.step()
        loss.item()
        records.append((batch.windows, time.perf_counter() - start))
    return records


# ---------------------------------------------------------------------------------------------------------------
# --memory: one step in a fresh process


def _status_kib(field: str) -> int | None:
    """A ``/proc/self/status`` field in KiB (``VmRSS``, ``VmHWM``), None where there is none (not Linux)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except OSError:
        pass
    return None


def _reset_peak() -> bool:
    """Reset this process's ``VmHWM`` to its current RSS (Linux >= 4.0); False where that is not possible."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def one_step(args, kind: str) -> dict:
    """The ``--_one-step`` child: one training step of ``kind`` (``every-window`` or ``per-window:B``) on the first
    flights that hold a batch, and the process's memory around it."""
    per_window = kind.startswith(PER_WINDOW)
    batch_size = int(kind.split(":")[1]) if per_window else args.chunk_batch
    parts, flights = [], []
    for name in args.flights:  # only as many flights as the batch needs
        seq = read_flights(args.data, [name])[0]
        part = per_window_data([seq]) if per_window else every_window_data([seq], args.chunk)
        parts.append(part)
        flights.append(name)
        del seq
        if sum(len(p) for p in parts) >= batch_size:
            break
    data = (concat_windows if per_window else concat_chunks)(parts)
    trainer = new_trainer(data, data, batch_size, args.seed)
    trainer.train = data.select(torch.arange(min(batch_size, len(data))))  # the step's batch, and nothing else
    trainer.val = trainer.train
    samples = trainer.train.gyro.shape[0] * trainer.train.gyro.shape[1]
    del data, parts
    gc.collect()
    before = _status_kib("VmRSS")
    reset = _reset_peak()
    ((windows, seconds),) = train_steps(trainer, steps=1)
    peak = _status_kib("VmHWM")
    return {
        "kind": PER_WINDOW if per_window else EVERY_WINDOW,
        "batch": len(trainer.train),
        "batch_unit": "windows" if per_window else "chunks",
        "windows": windows,
        "samples": samples,  # network input samples of the batch, context included
        "flights": flights,
        "seconds": seconds,
        "ru_maxrss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,  # KiB on Linux
        "rss_before_step_mib": None if before is None else before / 1024,
        "step_rise_mib": None if before is None or peak is None or not reset else (peak - before) / 1024,
    }


def measure_memory(args, kind: str) -> dict:
    """``one_step`` in a fresh process. It is started through ``/bin/sh``, which forks it: the kernel carries the
    peak RSS of the image an ``exec`` replaces into the new program's ``ru_maxrss``, so a child exec'd straight from
    this process (fork or vfork) would report at least this process's own peak; through the small shell it starts
    from the shell's."""
    command = [
        sys.executable,
        str(Path(__file__).resolve()),
        "--_one-step",
        kind,
        "--data",
        str(args.data),
        "--chunk",
        str(args.chunk),
        "--chunk-batch",
        str(args.chunk_batch),
        "--threads",
        str(args.threads),
        "--flights",
        ",".join(args.flights),
        "--seed",
        str(args.seed),
    ]
    shell = ["/bin/sh", "-c", '"$@"; exit $?', "sh"] if Path("/bin/sh").exists() else []
    done = subprocess.run(shell + command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"--memory step ({kind}) failed with status {done.returncode}:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


# ---------------------------------------------------------------------------------------------------------------
# the run


def time_per_window(train: TrainingData, batch_size: int, args) -> dict:
    """Windows/s of ``--per-window-steps`` steps at batch ``batch_size`` (after ``--warmup``); the epoch's time
    extrapolated from them."""
    trainer = new_trainer(train, train, batch_size, args.seed)
    train_steps(trainer, args.warmup)
    records = train_steps(trainer, args.per_window_steps)
    windows, seconds = sum(w for w, _ in records), sum(s for _, s in records)
    rate = windows / seconds
    return {
        "batch": batch_size,
        "windows_per_step": windows / len(records),
        "steps_timed": len(records),
        "step_seconds_median": statistics.median(s for _, s in records),
        "steps_per_epoch": math.ceil(len(train) / batch_size),
        "windows_per_s": rate,
        "epoch_seconds": len(train) / rate,
        "extrapolated": len(records) < math.ceil(len(train) / batch_size),
    }


def time_every_window(train: TrainingData, val: TrainingData | None, args) -> dict:
    """Full epochs of the every-window trainer (training only), then one validation pass if ``val``."""
    if args.warmup:
        train_steps(new_trainer(train, train, args.chunk_batch, args.seed), args.warmup)
    trainer = new_trainer(train, val if val is not None else train, args.chunk_batch, args.seed)
    epochs, records = [], []
    for _ in range(args.every_window_epochs):
        start = time.perf_counter()
        records += train_steps(trainer)
        epochs.append(time.perf_counter() - start)
    result = {
        "batch": args.chunk_batch,
        "windows_per_step": sum(w for w, _ in records) / len(records),
        "steps_per_epoch": math.ceil(len(train) / args.chunk_batch),
        "step_seconds_median": statistics.median(s for _, s in records),
        "epoch_seconds_each": epochs,
        "epoch_seconds": statistics.mean(epochs),
        "windows_per_s": train.windows * len(epochs) / sum(epochs),
        "validation_seconds": None,
    }
    if val is not None:
        start = time.perf_counter()
        trainer.validation_loss()
        result["validation_seconds"] = time.perf_counter() - start
    return result


def machine(threads: int) -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), cpu)
    except OSError:
        pass
    affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return {
        "cores": os.cpu_count(),
        "cores_usable": affinity,
        "cpu": cpu,
        "torch": torch.__version__,
        "threads": threads,
        "python": platform.python_version(),
    }


def commit() -> str | None:
    """The repository's commit (``+dirty`` with uncommitted changes), None outside a git checkout."""
    here = Path(__file__).resolve().parent
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=here, capture_output=True, text=True)
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"], cwd=here, capture_output=True, text=True
        )
    except OSError:
        return None
    if head.returncode != 0:
        return None
    return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


def plural(n: int, word: str) -> str:
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def positive_ints(text: str) -> list[int]:
    try:
        values = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated whole numbers, got {text!r}") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"expected whole numbers >= 1, got {text!r}")
    return values


def names(text: str) -> list[str]:
    values = [x.strip() for x in text.split(",") if x.strip()]
    if not values:
        raise argparse.ArgumentTypeError("expected at least one flight name")
    return values


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--data",
        type=Path,
        default=Path(__file__).resolve().parents[2] / "shared" / "data",
        help="the folder holding euroc/<flight> (default: ../shared/data beside the repository)",
    )
    parser.add_argument(
        "--flights",
        type=names,
        default=list(FLIGHTS),
        help="comma-separated EuRoC flights (default: the six training flights)",
    )
    parser.add_argument(
        "--per-window-steps",
        type=int,
        default=10,
        help="timed steps of the per-window trainer per batch size (the epoch is extrapolated)",
    )
    parser.add_argument("--warmup", type=int, default=2, help="untimed steps before each measurement")
    parser.add_argument("--every-window-epochs", type=int, default=1, help="full every-window epochs timed")
    parser.add_argument(
        "--batch-sizes", type=positive_ints, default=[16, 128], help="per-window batch sizes, windows (default 16,128)"
    )
    parser.add_argument("--chunk", type=int, default=3000, help="every-window chunk, samples (default 3000)")
    parser.add_argument("--chunk-batch", type=int, default=1, help="every-window batch, chunks (default 1)")
    parser.add_argument("--skip-validation", action="store_true", help="do not time the every-window validation")
    parser.add_argument("--threads", type=int, default=2, help="torch.set_num_threads (default 2)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--memory", action="store_true", help="peak RSS of one training step (fresh processes)")
    parser.add_argument("--json", default=None, help="write the results to this file")
    parser.add_argument("--_one-step", dest="one_step", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    for key in ("per_window_steps", "every_window_epochs", "chunk_batch", "threads"):
        if getattr(args, key) < 1:
            parser.error(f"--{key.replace('_', '-')} must be at least 1")
    if args.warmup < 0:
        parser.error("--warmup must be at least 0")
    if args.chunk < WINDOW:
        parser.error(f"--chunk must be at least the window, {WINDOW} samples")
    return args


def main(argv=None) -> None:
    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    if args.one_step is not None:
        print(json.dumps(one_step(args, args.one_step)))
        return

    info = machine(torch.get_num_threads())
    print(f"torch {info['torch']}, {info['threads']} threads, {info['cores']} cores ({info['cpu']})")
    memory = []
    if args.memory:  # first: fresh processes, before this one holds any data
        kinds = [EVERY_WINDOW] + [f"{PER_WINDOW}:{b}" for b in args.batch_sizes]
        memory = [measure_memory(args, kind) for kind in kinds]

    start = time.perf_counter()
    sequences = read_flights(args.data, args.flights)
    read_seconds = time.perf_counter() - start
    samples = sum(len(s) for s in sequences)
    print(
        f"{len(sequences)} flights, {samples:,} samples ({samples / 200 / 60:.1f} min at 200 Hz), read in "
        f"{read_seconds:.1f} s: {', '.join(args.flights)}"
    )
    print(
        f"windows of {WINDOW} samples every {STRIDE} samples, supervised every {EVERY}, context {CONTEXT}; "
        f"AirImuNet() seed {args.seed}, LossWeights() with covariance, Adam lr {LR:g}"
    )

    start = time.perf_counter()
    windows = per_window_data(sequences)
    cut_windows = time.perf_counter() - start
    n_windows = len(windows)
    per_window = {}
    for b in args.batch_sizes:
        per_window[b] = time_per_window(windows, b, args)
    del windows
    gc.collect()

    start = time.perf_counter()
    chunks = every_window_data(sequences, args.chunk)
    cut_chunks = time.perf_counter() - start
    val = None if args.skip_validation else every_window_data(sequences, args.chunk, VAL_STRIDE)
    n_chunk_windows, n_chunks = chunks.windows, len(chunks)
    per_chunk = len(chunks.starts)
    chunk_samples = chunks.gyro.shape[1]
    print(
        f"per-window: {n_windows:,} windows of {CONTEXT + WINDOW} input samples (cut in {cut_windows:.1f} s); "
        f"every-window: {n_chunks} chunks of {chunk_samples} input samples ({chunk_samples - CONTEXT} + context), "
        f"{per_chunk} window starts each, {n_chunk_windows:,} valid windows (cut in {cut_chunks:.1f} s)"
    )
    if n_chunk_windows != n_windows:
        print(f"WARNING: the chunks hold {n_chunk_windows:,} windows, make_windows cuts {n_windows:,}")
    if val is not None:
        print(f"validation: {len(val)} chunks, {val.windows:,} windows every {VAL_STRIDE} samples")
    every = time_every_window(chunks, val, args)

    ratio_by_batch = {b: every["windows_per_s"] / r["windows_per_s"] for b, r in per_window.items()}
    reference = 16 if 16 in per_window else args.batch_sizes[0]
    train_minutes = SCHEDULE_EPOCHS * every["epoch_seconds"] / 60
    with_val = None
    if every["validation_seconds"] is not None:
        with_val = SCHEDULE_EPOCHS * (every["epoch_seconds"] + every["validation_seconds"]) / 60

    print()
    header = f"{'trainer':13s} {'batch':>11s} {'windows/step':>12s} {'windows/s':>10s} {'epoch (s)':>10s}"
    print(f"{header}  {'every/per':>9s}  note")
    for b, r in per_window.items():
        note = f"extrapolated from {plural(r['steps_timed'], 'step')}" if r["extrapolated"] else "a full epoch"
        note += f" of {r['steps_per_epoch']:,}; step median {r['step_seconds_median'] * 1e3:.0f} ms"
        print(
            f"{PER_WINDOW:13s} {plural(b, 'window'):>11s} {r['windows_per_step']:12.1f} {r['windows_per_s']:10.1f} "
            f"{r['epoch_seconds']:10.1f}  {ratio_by_batch[b]:8.2f}x  {note}"
        )
    epochs = ", ".join(f"{s:.1f}" for s in every["epoch_seconds_each"])
    print(
        f"{EVERY_WINDOW:13s} {plural(args.chunk_batch, 'chunk'):>11s} {every['windows_per_step']:12.1f} "
        f"{every['windows_per_s']:10.1f} {every['epoch_seconds']:10.1f}  {'':>9s}  "
        f"measured: {plural(len(every['epoch_seconds_each']), 'full epoch')} of {every['steps_per_epoch']} steps "
        f"({epochs} s); "
        f"step median {every['step_seconds_median'] * 1e3:.0f} ms"
    )
    print()
    line = f"official schedule ({SCHEDULE_EPOCHS} epochs), every-window: training {train_minutes:.1f} min"
    if with_val is not None:
        line += (
            f"; validation {every['validation_seconds']:.1f} s an epoch ({len(val)} chunks, "
            f"{val.windows:,} windows), with it {with_val:.1f} min"
        )
    print(line)
    for m in memory:
        step = "n/a" if m["step_rise_mib"] is None else f"{m['step_rise_mib']:.0f} MiB"
        print(
            f"memory, one {m['kind']} step of {plural(m['batch'], m['batch_unit'][:-1])} "
            f"({plural(m['windows'], 'window')}, "
            f"{m['samples']:,} input samples): peak RSS (ru_maxrss) {m['ru_maxrss_mib']:.0f} MiB, the step "
            f"{step} above {m['rss_before_step_mib']:.0f} MiB before it ({m['seconds']:.2f} s; reads "
            f"{', '.join(m['flights'])})"
        )

    if args.json:
        result = {
            "per_window_windows_per_s": per_window[reference]["windows_per_s"],
            "per_window_reference_batch": reference,
            "per_window_by_batch": {str(b): r["windows_per_s"] for b, r in per_window.items()},
            "per_window_epoch_seconds_by_batch": {str(b): r["epoch_seconds"] for b, r in per_window.items()},
            "per_window_details": {str(b): r for b, r in per_window.items()},
            "every_window_windows_per_s": every["windows_per_s"],
            "every_window_epoch_seconds": every["epoch_seconds"],
            "every_window_details": every,
            "ratio": ratio_by_batch[reference],
            "ratio_by_batch": {str(b): v for b, v in ratio_by_batch.items()},
            "validation_seconds_per_epoch": every["validation_seconds"],
            "official_schedule_epochs": SCHEDULE_EPOCHS,
            "official_schedule_minutes": train_minutes,  # training only
            "official_schedule_with_validation_minutes": with_val,
            "data": {
                "flights": args.flights,
                "samples": samples,
                "windows": n_windows,
                "chunks": n_chunks,
                "chunk_windows": n_chunk_windows,
                "window_starts_per_chunk": per_chunk,
                "chunk_input_samples": chunk_samples,
                "validation_chunks": None if val is None else len(val),
                "validation_windows": None if val is None else val.windows,
            },
            "memory": memory or None,
            "machine": info,
            "settings": {
                "window": WINDOW,
                "every": EVERY,
                "stride": STRIDE,
                "context": CONTEXT,
                "val_stride": VAL_STRIDE,
                "chunk": args.chunk,
                "chunk_batch": args.chunk_batch,
                "batch_sizes": args.batch_sizes,
                "per_window_steps": args.per_window_steps,
                "warmup": args.warmup,
                "every_window_epochs": args.every_window_epochs,
                "lr": LR,
                "seed": args.seed,
                "validation": val is not None,
                "data": str(args.data),
            },
            "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
            "commit": commit(),
        }
        with atomic_file(args.json) as f:
            json.dump(result, f, indent=2)
            f.write("\n")
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()

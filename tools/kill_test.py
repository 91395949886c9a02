"""SIGKILL the writing commands at random moments and check what they leave (BENCHMARKS.md, Faults).

    python tools/kill_test.py --kills 20 [--commands train,export,fuse,ablate-pgo] [--json FILE]

For each command: one uninterrupted run times it, then ``--kills`` runs are killed with SIGKILL (no clean-up code
runs) after a random delay, uniform over that time (seeded), and checked:

- train (a tiny simulated config, 6 epochs): the killed run resumes to the end; the epochs lost, those the killed
  run had finished (its stdout's epoch lines) less those in its ``last.pt``, are at most one;
- export (EuRoC V1_02, 1-s keyframes): the output path holds no file, or one ``factors.load_export`` accepts;
- fuse (KITTI 2011_10_03_0027 with GTSAM's GPS, one fix in ten): a folder with ``summary.json`` has every file it
  lists complete (each read back), and a folder without it is not taken for complete;
- ablate-pgo (the simulator, a tiny model trained once beforehand): ``--json`` is absent or the whole table;
- and while one of each runs, the same command into the same folder is refused naming the writer (train, fuse,
  ablate-pgo; an export is one file written by rename, no folder to lock).

Prints a line per command (kills, kills that landed before the end, violations) and, with ``--json``, writes them.
Run from the repository root with ``../shared/data`` beside it.
"""

from __future__ import annotations

import argparse
import functools
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"
AIRIMU = str(Path(sys.executable).with_name("airimu"))
TRAIN_YAML = """
name: kill
data:
  train: [{dataset: simulator, options: {duration_s: 10.0, seed: 1, device_seed: 5}}]
  val: [{dataset: simulator, options: {duration_s: 5.0, seed: 2, device_seed: 5}}]
model: {conv_channels: [8, 16], gru_sizes: [16], decoder_hidden: 16}
train: {window: 200, every: 50, batch_size: 4, epochs: 6, lr: 3e-3, calibration_steps: 10}
"""
EPOCHS = 6
KITTI = [
    "--dataset",
    "kitti_raw",
    "--path",
    str(DATA / "kitti_raw" / "2011_10_03_drive_0027.csv"),
    "--reader-option",
    "on_backward=drop",
    "--reader-option",
    "on_duplicate=drop",
    "--reader-option",
    "on_gap=keep",
    "--gps",
    str(DATA / "kitti_gtsam" / "KittiGps_converted.txt"),
    "--gps-every",
    "10",
    "--keyframes",
    "1s",
]


def commands(work: Path) -> dict:
    """Per command: (argv for an output place, the output place, the check of what a killed run left)."""
    (work / "kill.yaml").write_text(TRAIN_YAML)
    (work / "kill_long.yaml").write_text(TRAIN_YAML.replace("epochs: 6", "epochs: 60"))  # for the second-writer test
    (work / "pgo_model.yaml").write_text(TRAIN_YAML.replace("epochs: 6", "epochs: 2"))
    for name, seeds in (("pgo.yaml", 2), ("pgo_long.yaml", 40)):  # pgo_long: for the second-writer test
        (work / name).write_text(
            f"name: kill_pgo\nexperiment: pgo_model.yaml\nrun: {work / 'pgo_model'}\n"
            f"options: {{gps_hz: [1.0], seeds: {seeds}, keyframe_interval_s: 0.2}}\n"
        )
    return {
        "train": (
            lambda out, config="kill.yaml": [
                AIRIMU,
                "train",
                "--config",
                str(work / config),
                "--out",
                str(out),
                "--no-progress",
            ],
            check_train,
        ),
        "export": (
            lambda out: [
                AIRIMU,
                "export",
                "--dataset",
                "euroc",
                "--path",
                str(DATA / "euroc" / "V1_02_medium"),
                "--out",
                str(out / "e.npz"),
                "--keyframes",
                "1s",
                "--gyro-noise-density",
                "1.7e-4",
                "--acc-noise-density",
                "2e-3",
            ],
            check_export,
        ),
        "fuse": (lambda out: [AIRIMU, "fuse", *KITTI, "--out", str(out)], check_fuse),
        "ablate-pgo": (
            lambda out, config="pgo.yaml": [
                AIRIMU,
                "ablate-pgo",
                "--config",
                str(work / config),
                "--out",
                str(out),
                "--json",
                str(out / "table.json"),
                "--no-progress",
            ],
            check_pgo,
        ),
    }


def check_train(out: Path, stdout: str, argv: list[str]) -> list[str]:
    from learned_imu.network.checkpoint import load_checkpoint

    finished = stdout.count(" epoch ")  # one line per finished epoch on the console
    done = load_checkpoint(out / "last.pt").trainer["epochs_done"] if (out / "last.pt").exists() else 0
    problems = [f"lost {finished - done} epochs"] if finished - done > 1 else []
    resumed = subprocess.run(argv, capture_output=True, text=True, timeout=900)
    if resumed.returncode != 0:
        return [*problems, f"resume failed: {resumed.stderr.strip().splitlines()[-1:]}"]
    lines = [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines()]
    if [e["epoch"] for e in lines] != list(range(EPOCHS)):
        problems.append(f"metrics after resuming: epochs {[e['epoch'] for e in lines]}")
    return problems


def check_export(out: Path, stdout: str, argv: list[str]) -> list[str]:
    from factors import load_export

    path = out / "e.npz"
    if not path.exists():
        return []
    try:
        load_export(path)
    except Exception as error:  # noqa: BLE001 (any failure to read back is the finding)
        return [f"e.npz present but unreadable: {error}"]
    return []


def check_fuse(out: Path, stdout: str, argv: list[str]) -> list[str]:
    if not (out / "summary.json").exists():
        return []  # not complete, and does not look it
    problems = []
    try:
        json.loads((out / "summary.json").read_text())
        for name in ("fused.tum", "fused_imu_rate.tum"):
            rows = np.loadtxt(out / name, ndmin=2)
            if rows.shape[1] != 8 or len(rows) < 2:
                problems.append(f"{name}: {rows.shape}")
        with np.load(out / "marginals.npz", allow_pickle=False) as marginals:
            if marginals["pos_cov"].shape[0] != marginals["t"].shape[0]:
                problems.append("marginals.npz: t and pos_cov disagree")
        if (out / "fused.png").read_bytes()[:8] != b"\x89PNG\r\n\x1a\n" or not (out / "fused.rrd").stat().st_size:
            problems.append("fused.png or fused.rrd incomplete")
    except Exception as error:  # noqa: BLE001
        problems.append(f"summary.json present but a file is not complete: {error}")
    return problems


def check_pgo(out: Path, stdout: str, argv: list[str]) -> list[str]:
    table = out / "table.json"
    if not table.exists():
        return []
    try:
        rows = json.loads(table.read_text())
    except ValueError as error:
        return [f"table.json present but not JSON: {error}"]
    return [] if len(rows) == 4 else [f"table.json has {len(rows)} rows, 4 expected"]


def busy_refused(argv_of, out: Path) -> bool | None:
    """While one run writes ``out``, a second into it exits with the writer lock's message (None: the first ended
    before the second could be tried)."""
    first = subprocess.Popen(argv_of(out), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while not (out / ".lock").exists() and time.monotonic() < deadline and first.poll() is None:
            time.sleep(0.05)
        time.sleep(0.5)
        if first.poll() is not None:
            return None  # the first ended before a second could start: not measured
        second = subprocess.run(argv_of(out), capture_output=True, text=True, timeout=600)
        running = first.poll() is None
        refused = second.returncode != 0 and "another writer holds it" in second.stderr
        return refused if running or refused else None  # the first ended meanwhile: not measured
    finally:
        first.kill()
        first.wait()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kills", type=int, default=20)
    parser.add_argument("--commands", default="train,export,fuse,ablate-pgo")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", dest="json_out")
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    results = {}
    with tempfile.TemporaryDirectory() as folder:
        work = Path(folder)
        table = commands(work)
        if "ablate-pgo" in args.commands:  # its model trained once, so that the kills land in the ablation
            subprocess.run(
                [
                    AIRIMU,
                    "train",
                    "--config",
                    str(work / "pgo_model.yaml"),
                    "--out",
                    str(work / "pgo_model"),
                    "--no-progress",
                ],
                check=True,
                capture_output=True,
            )
        for name in args.commands.split(","):
            argv_of, check = table[name]
            start = time.perf_counter()
            subprocess.run(argv_of(work / f"{name}-ref"), check=True, capture_output=True)
            whole = time.perf_counter() - start
            landed, problems = 0, []
            for k in range(args.kills):
                out = work / f"{name}-{k}"
                out.mkdir()
                argv = argv_of(out)
                proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
                time.sleep(rng.uniform(0.0, whole))
                landed += proc.poll() is None
                proc.kill()  # SIGKILL
                stdout = proc.communicate()[0] or ""
                problems += [f"kill {k}: {p}" for p in check(out, stdout, argv)]
            longer = {"train": "kill_long.yaml", "ablate-pgo": "pgo_long.yaml"}  # runs long enough to meet a second
            busy = functools.partial(argv_of, config=longer[name]) if name in longer else argv_of
            lock = busy_refused(busy, work / f"{name}-busy") if name != "export" else None
            results[name] = {
                "kills": args.kills,
                "landed_before_the_end": landed,
                "uninterrupted_s": round(whole, 1),
                "violations": problems,
                "second_writer_refused": lock,
            }
            print(
                f"{name}: {args.kills} SIGKILLs, {landed} before the end (a run takes {whole:.1f} s); "
                f"violations: {len(problems)}; a second writer refused: {lock}",
                flush=True,
            )
            for problem in problems:
                print(f"  {problem}", flush=True)
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(results, indent=2) + "\n")
    return 1 if any(r["violations"] or r["second_writer_refused"] is False for r in results.values()) else 0


if __name__ == "__main__":
    sys.exit(main())

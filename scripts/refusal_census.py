"""Refusal census ("every bad value gets a clear error"): hostile inputs per class, run on two trees.

    python scripts/refusal_census.py --before /tmp/airimu-before --after /work/main

Each case runs in a fresh process (``python -m airimu.cli ...`` or a ``python -c`` snippet) with
``PYTHONPATH=<tree>`` and a scratch working directory, and ends in one of:

- clean: exit 2 and stderr starting ``airimu: error:`` or typer's usage box (``Invalid value`` / ``Error``), no
  ``Traceback``; a library snippet: an exception of the toolkit's own types (AirImuError's subclasses, ExportError,
  GraphError), printed as ``Type: message``.
- traceback: any ``Traceback`` in stderr, exit 1 (or any other non-clean ending); a snippet: any other exception type.
- exit-0: accepted silently (a snippet: no exception; a case whose timeout means "it started the work": timed out).
- hang: still running at the timeout (120 s unless the case says otherwise); the process group is killed.

The "5-s" cases (config values, ``train --out <file>``) get 5 s beyond the tree's start-up: the time its
``train --config <missing file>`` takes to refuse (slowest of two, measured before the cases), which on a loaded
2-core machine is itself 3-9 s.

The test inputs are built once, with the AFTER tree, from the project's simulator.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
from dataclasses import dataclass, field
from pathlib import Path

CLEAN_TYPES = {
    "ConfigError",
    "DataError",
    "InputError",
    "FolderBusyError",
    "DependencyError",
    "ExportError",
    "GraphError",
}
OUTCOMES = ("clean", "traceback", "exit-0", "hang")
SENTINEL = "@@CENSUS-RESULT@@"
HEADER = "t,gx,gy,gz,ax,ay,az,px,py,pz,qw,qx,qy,qz,vx,vy,vz"
CSV_KEYS = dict(header=True, time="t", gyro=["gx", "gy", "gz"], acc=["ax", "ay", "az"])
GT_KEYS = dict(gt_pos=["px", "py", "pz"], gt_quat=["qw", "qx", "qy", "qz"], gt_vel=["vx", "vy", "vz"])


@dataclass
class Case:
    cls: str
    name: str
    cli: list[str] | None = None  # arguments after ``python -m airimu.cli``
    code: str | None = None  # a library snippet (prints SENTINEL then ``Type: message`` or ``OK``)
    timeout: float = 120.0
    after_startup: bool = False  # the timeout counts from the tree's measured start-up time
    timeout_is_accepted: bool = False  # still running at the timeout = it started the work (exit-0 class)
    memory_limit: int | None = None  # RLIMIT_AS, bytes
    cleanup: list[Path] = field(default_factory=list)


@dataclass
class Result:
    outcome: str
    code: int | None
    last_line: str
    seconds: float


# ---- inputs ---------------------------------------------------------------------------------------------------------

MAKE_INPUTS = r"""
import sys
from pathlib import Path
import numpy as np
import torch
from learned_imu.datasets.simulator import simulate
from airimu_core.rotations import matrix_to_quat_wxyz
from learned_imu.export import export_preintegration, keyframes_every
from learned_imu.network.checkpoint import build_model
from learned_imu.config import DataConfig, ExperimentConfig, ModelConfig, SequenceConfig
from airimu_core.config import to_dict

folder = Path(sys.argv[1])
seq = simulate("drone", duration_s=30.0, rate_hz=100.0, gps_rate_hz=1.0, gps_sigma_m=0.1, seed=1)
np.save(folder / "flight_t.npy", seq.t)
HEADER = "t,gx,gy,gz,ax,ay,az,px,py,pz,qw,qx,qy,qz,vx,vy,vz"


def write_csv(path, pos_scale=1.0, vel_scale=1.0):
    quat = matrix_to_quat_wxyz(seq.gt.rot)
    rows = np.column_stack([seq.t, seq.gyro, seq.acc, pos_scale * seq.gt.pos, quat, vel_scale * seq.gt.vel])
    np.savetxt(path, rows, delimiter=",", header=HEADER, comments="")


write_csv(folder / "imu.csv")
for name, p, v in [("mm", 1000.0, 1000.0), ("cm", 100.0, 100.0), ("km", 0.001, 0.001), ("negvel", 1.0, -1.0),
                   ("mm_pos_only", 1000.0, 1.0)]:
    write_csv(folder / f"gt_{name}.csv", p, v)
np.savetxt(folder / "imu_only.csv", np.column_stack([seq.t, seq.gyro, seq.acc]), delimiter=",",
           header="t,gx,gy,gz,ax,ay,az", comments="")
np.savetxt(folder / "imu_only_ns.csv", np.column_stack([seq.t * 1e9, seq.gyro, seq.acc]), delimiter=",",
           header="t,gx,gy,gz,ax,ay,az", comments="", fmt="%.10g")
gps = seq.gps
mav0 = folder / "euroc" / "mav0"  # the same flight as a EuRoC folder: ground truth readable by default on both trees
(mav0 / "imu0").mkdir(parents=True)
(mav0 / "state_groundtruth_estimate0").mkdir()
ns = np.round(seq.t * 1e9).astype(np.int64)
np.savetxt(mav0 / "imu0" / "data.csv", np.column_stack([ns, seq.gyro, seq.acc]), delimiter=",",
           header="timestamp,wx,wy,wz,ax,ay,az", fmt=["%d"] + ["%.9g"] * 6)
gt = np.column_stack([ns, seq.gt.pos, matrix_to_quat_wxyz(seq.gt.rot), seq.gt.vel, np.zeros((len(ns), 6))])
np.savetxt(mav0 / "state_groundtruth_estimate0" / "data.csv", gt, delimiter=",", header="timestamp,...",
           fmt=["%d"] + ["%.12g"] * 16)
np.savetxt(folder / "gps.csv", np.column_stack([gps.t, gps.pos]), delimiter=",", header="t,x,y,z", comments="")
np.savetxt(folder / "gps_two.csv", np.column_stack([gps.t[:2], gps.pos[:2]]), delimiter=",", header="t,x,y,z",
           comments="")
close = gps.pos[0] + np.array([[0.0, 0.0, 0.0], [0.7, 0.0, 0.0], [0.0, 0.7, 0.0]])  # all within 1 m of each other
np.savetxt(folder / "gps_three_close.csv", np.column_stack([gps.t[:3], close, np.ones(3)]), delimiter=",",
           header="t,x,y,z,sigma", comments="")
(folder / "empty.mat").write_bytes(b"")
(folder / "random.bag").write_bytes(np.random.default_rng(0).bytes(5000))
(folder / "random.csv").write_bytes(np.random.default_rng(1).bytes(5000))
(folder / "a_folder").mkdir()
(folder / "existing_file").write_text("x")
export_preintegration(folder / "seq.npz", seq, keyframes_every(seq, 0.5), 1e-6, 1e-4)
model = build_model(ModelConfig(conv_channels=(8, 16), gru_sizes=(16,), decoder_hidden=16))
state = model.state_dict()
name = next(k for k, v in state.items() if v.is_floating_point())
state[name].view(-1)[0] = float("nan")
config = to_dict(ExperimentConfig("nan", DataConfig((SequenceConfig("simulator"),), (SequenceConfig("simulator"),)),
                                  model=ModelConfig(conv_channels=(8, 16), gru_sizes=(16,), decoder_hidden=16)))
# format version 1 written by hand: both trees read it (the "before" tree reads only version 1)
torch.save({"format": "airimu-checkpoint", "version": 1, "config": config, "trainer": {"model": state}, "best": {}},
           folder / "nan.pt")
print(name)
"""

EXPORT_CORRUPTIONS = {
    "zero delta_cov[3]": ("delta_cov", "a[3] = 0.0"),
    "asymmetric delta_cov[3][0,5]=1": ("delta_cov", "a[3, 0, 5] = 1.0"),
    "delta_dt[2]=0": ("delta_dt", "a[2] = 0.0"),
    "delta_dt[2]=-0.5": ("delta_dt", "a[2] = -0.5"),
    "delta_rot[1][0,0]=2": ("delta_rot", "a[1, 0, 0] = 2.0"),
    "keyframe_index[2:4] swapped": ("keyframe_index", "a[2:4] = a[2:4][::-1].copy()"),
    "keyframe_index[-1]=10**6": ("keyframe_index", "a[-1] = 10**6"),
    "gravity negated": ("gravity", "a *= -1.0"),
    "gravity zero": ("gravity", "a[:] = 0.0"),
    "gyro_cov[5]=0": ("gyro_cov", "a[5] = 0.0"),
}


def make_inputs(after: Path, folder: Path) -> str:
    """Writes the inputs into ``folder``; returns the name of the checkpoint's NaN weight."""
    env = dict(os.environ, PYTHONPATH=str(after))
    env.pop("AIRIMU_DEBUG", None)
    made = subprocess.run(
        [sys.executable, "-c", MAKE_INPUTS, str(folder)],
        cwd=folder,
        env=env,
        check=True,
        stdout=subprocess.PIPE,
        text=True,
    )
    import numpy as np

    with np.load(folder / "seq.npz", allow_pickle=False) as data:
        clean = {k: data[k].copy() for k in data.files}
    for i, (_label, (key, change)) in enumerate(EXPORT_CORRUPTIONS.items()):
        arrays = {k: v.copy() for k, v in clean.items()}
        exec(change, {}, {"a": arrays[key]})  # noqa: S102 - fixed strings above
        np.savez(folder / f"bad_export_{i}.npz", **arrays)
    configs = folder / "configs"
    configs.mkdir()
    for i, (_, text) in enumerate(config_cases()):
        (configs / f"config_{i}.yaml").write_text(text)
    return made.stdout.strip().splitlines()[-1]


# ---- cases ----------------------------------------------------------------------------------------------------------


def reader_options(keys: dict) -> list[str]:
    out = []
    for key, value in keys.items():
        text = f"[{','.join(value)}]" if isinstance(value, list) else str(value).lower()
        out += ["--reader-option", f"{key}={text}"]
    return out


SMALL_SIM = "{dataset: simulator, options: {duration_s: 10.0}}"


def config_cases() -> list[tuple[str, str]]:
    def data(spec: str) -> str:
        return f"name: census\ndata:\n  train: [{spec}]\n  val: [{SMALL_SIM}]\n"

    def number(section: str, key: str, value: str) -> str:
        return data(SMALL_SIM) + f"{section}:\n  {key}: {value}\n"

    levels = ["a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    levels += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 9)]
    body = "\n".join(f"      {line}" for line in levels)
    bomb = f"name: census\ndata:\n  train:\n  - dataset: simulator\n    options:\n{body}\n  val: [{SMALL_SIM}]\n"
    return [
        ("simulator option typo sede: 3", data("{dataset: simulator, options: {sede: 3}}")),
        ("euroc reader option typo imu_fle: a.csv", data("{dataset: euroc, path: x, options: {imu_fle: a.csv}}")),
        ("duration_s: long", data("{dataset: simulator, options: {duration_s: long}}")),
        ("rate_hz: 0", data("{dataset: simulator, options: {rate_hz: 0}}")),
        ("duration_s: -5", data("{dataset: simulator, options: {duration_s: -5}}")),
        ("gps_sigma_m: .nan", data("{dataset: simulator, options: {gps_sigma_m: .nan}}")),
        ("profile: boat", data("{dataset: simulator, options: {profile: boat}}")),
        ("euroc on_gap: skip", data("{dataset: euroc, path: x, options: {on_gap: skip}}")),
        ("dataset: tumvi", data("{dataset: tumvi, path: x}")),
        ("nested alias bomb in options (10^9)", bomb),
        ("train.lr: 0", number("train", "lr", "0")),
        ("train.lr: -1", number("train", "lr", "-1")),
        ("train.batch_size: 0", number("train", "batch_size", "0")),
        ("model.dropout: 1.5", number("model", "dropout", "1.5")),
        ("train.plateau_factor: 1.0", number("train", "plateau_factor", "1.0")),
        ("evaluation.interval: 0", number("evaluation", "interval", "0")),
    ]


def snippet(body: str) -> str:
    """A library call whose exception (or none) is printed after SENTINEL as ``Type: message``."""
    return (
        "import sys\n"
        "try:\n" + textwrap.indent(textwrap.dedent(body), "    ") + "\n"
        "except Exception as e:\n"
        f"    print({SENTINEL!r}); print(f'{{type(e).__name__}}: {{e}}'); sys.exit(0)\n"
        f"print({SENTINEL!r}); print('OK')\n"
    )


def build_cases(d: Path) -> list[Case]:
    imu, imu_only = str(d / "imu.csv"), str(d / "imu_only.csv")
    csv_opts = reader_options(CSV_KEYS)
    cases: list[Case] = []

    # 1. CLI values: each on an input that both trees read and process without the bad value
    euroc = str(d / "euroc")
    ev = ["evaluate", "--dataset", "euroc", "--path", euroc]
    ev_csv = ["evaluate", "--dataset", "csv", "--path", imu]
    ex = ["export", "--dataset", "csv", "--path", imu_only, "--out", "e.npz"]  # default columns fit imu_only.csv
    dens = ["--gyro-noise-density", "0.004", "--acc-noise-density", "0.08"]
    fu = ["fuse", "--dataset", "csv", "--path", imu, "--gps", str(d / "gps.csv"), *csv_opts]
    cli_values = {
        "evaluate --dataset foo": ["evaluate", "--dataset", "foo", "--path", euroc],
        "evaluate --interval 0": [*ev, "--interval", "0"],
        "evaluate --interval -1": [*ev, "--interval", "-1"],
        "evaluate --interval nan": [*ev, "--interval", "nan"],
        "evaluate --interval-unit minutes": [*ev, "--interval-unit", "minutes"],
        "export --keyframes 0s": [*ex, "--keyframes", "0s", *dens],
        "export --keyframes abc": [*ex, "--keyframes", "abc", *dens],
        "export --keyframes infs": [*ex, "--keyframes", "infs", *dens],
        "export --gyro-noise-density -1.7e-4": [*ex, "--gyro-noise-density", "-1.7e-4", "--acc-noise-density", "0.08"],
        "export --gyro-noise-density 0": [*ex, "--gyro-noise-density", "0", "--acc-noise-density", "0.08"],
        "fuse --gps-every 0": [*fu, "--out", "f", "--gps-every", "0"],
        "ablate-pgo --config pgo_demo.yaml --epochs 0": ["ablate-pgo", "--config", "pgo_demo.yaml", "--epochs", "0"],
        "train --config demo.yaml --epochs 0": ["train", "--config", "demo.yaml", "--out", "run", "--epochs", "0"],
        "evaluate --reader-option sede=1": [*ev_csv, "--reader-option", "sede=1"],
        "fuse --reader-option sede=1": [*fu, "--out", "f", "--reader-option", "sede=1"],
        "evaluate --reader-option gravity=up": [*ev_csv, "--reader-option", "gravity=up"],
    }
    for name, args in cli_values.items():
        accepted = name.startswith(("ablate-pgo", "train"))  # still running at the timeout: it is training
        cases.append(Case("1 CLI values", name, cli=args, timeout_is_accepted=accepted))

    # 2. Config values: train must fail before training (5 s)
    for i, (name, _) in enumerate(config_cases()):
        args = ["train", "--config", str(d / "configs" / f"config_{i}.yaml"), "--out", "run", "--epochs", "1"]
        cases.append(Case("2 Config values", name, cli=args, timeout=5.0, timeout_is_accepted=True, after_startup=True))

    # 3. Files
    big = d / "big.csv"
    files = {
        "broad: zero-byte .mat": (["--dataset", "broad", "--path", str(d / "empty.mat")], {}),
        "rosbag: 5000 random bytes": (["--dataset", "rosbag", "--path", str(d / "random.bag")], {}),
        "csv: 5000 random bytes": (["--dataset", "csv", "--path", str(d / "random.csv")], {}),
        "csv: a folder": (["--dataset", "csv", "--path", str(d / "a_folder")], {}),
        "csv: a missing file": (["--dataset", "csv", "--path", str(d / "nothing.csv")], {}),
        "csv without ground truth (+reader options)": (["--dataset", "csv", "--path", imu_only, *csv_opts], {}),
        "csv: 10-GB sparse file": (
            ["--dataset", "csv", "--path", str(big)],
            dict(timeout=60.0, memory_limit=8 << 30, cleanup=[big]),
        ),
    }
    for name, (args, extra) in files.items():
        cases.append(Case("3 Files", f"evaluate {name}", cli=["evaluate", *args], **extra))

    # 4. Units and frames (library)
    keys = f"**{CSV_KEYS!r}"
    units = {
        "positions and velocity in mm": ("gt_mm.csv", True),
        "positions and velocity in cm": ("gt_cm.csv", True),
        "positions and velocity in km": ("gt_km.csv", True),
        "velocity negated": ("gt_negvel.csv", True),
        "positions in mm, velocity in m/s": ("gt_mm_pos_only.csv", True),
        "time column in ns (no ground truth)": ("imu_only_ns.csv", False),
    }
    for name, (file, gt) in units.items():
        extra = f", **{GT_KEYS!r}" if gt else ""
        body = f"""
            from learned_imu.datasets import read_sequence
            read_sequence("csv", {str(d / file)!r}, {keys}{extra})
        """
        cases.append(Case("4 Units/frames", name, code=snippet(body)))

    # 5. Exports (library, every backend)
    for backend, bias in (("gtsam", "lambda k: k"), ("custom", "None")):
        for i, label in enumerate(EXPORT_CORRUPTIONS):
            body = f"""
                from factors.export_file import from_export
                from_export({str(d / f"bad_export_{i}.npz")!r}, backend={backend!r}, bias_key={bias})
            """
            cases.append(Case("5 Exports", f"{backend}: {label}", code=snippet(body)))

    # 6. Graphs
    fuse_gps = ["fuse", "--dataset", "csv", "--path", imu_only, "--out", "f", *csv_opts, "--gps"]
    cases.append(Case("6 Graphs", "fuse: 2 GPS fixes", cli=[*fuse_gps, str(d / "gps_two.csv")]))
    three_close = [*fuse_gps, str(d / "gps_three_close.csv")]
    cases.append(Case("6 Graphs", "fuse: 3 fixes within 1 m, sigma 1 m", cli=three_close))
    body = """
        import torch
        from learned_imu.datasets.simulator import simulate
        from learned_imu.network.model import Correction
        from airimu.experiments.pgo import PgoOptions, run_sequence
        seq = simulate("drone", duration_s=30.0, rate_hz=100.0, gps_rate_hz=1.0, gps_sigma_m=0.1, seed=1)
        gyro, acc = torch.as_tensor(seq.gyro), torch.as_tensor(seq.acc)
        zero = torch.zeros_like(gyro)
        c = Correction(gyro, acc, zero, zero, torch.full_like(gyro, 1e-6), torch.full_like(acc, 1e-4))
        from pathlib import Path
        run_sequence(seq, c, Path("pgo_out"), PgoOptions(gps_hz=(0.02,), seeds=1))
    """
    cases.append(Case("6 Graphs", "run_sequence at gps_hz 0.02 (1 fix)", code=snippet(body)))

    # 7. Outputs
    folder, existing = str(d / "a_folder"), str(d / "existing_file")
    cases += [
        Case("7 Outputs", "evaluate --json <folder>", cli=[*ev, "--json", folder]),
        Case(
            "7 Outputs",
            "export --out <folder>",
            cli=["export", "--dataset", "csv", "--path", imu_only, "--out", folder, *dens],
        ),
        Case("7 Outputs", "fuse --out <existing file>", cli=[*fu, "--out", existing]),
        Case(
            "7 Outputs",
            "train --out <existing file>",
            cli=["train", "--config", "demo.yaml", "--out", existing, "--epochs", "1"],
            timeout=5.0,
            timeout_is_accepted=True,
            after_startup=True,
        ),
    ]

    # 8. Checkpoints
    cases.append(
        Case(
            "8 Checkpoints",
            "export-model of a NaN-weight checkpoint",
            cli=["export-model", "--checkpoint", str(d / "nan.pt"), "--format", "torchscript", "--out", "m.pt"],
        )
    )
    return cases


# ---- running and classifying --------------------------------------------------------------------------------------


def last_line(text: str) -> str:
    lines = [line.strip(" │╭╮╰╯─") for line in text.strip().splitlines()]
    lines = [line for line in lines if line]
    return lines[-1][:200] if lines else ""


def startup_seconds(tree: Path, scratch: Path) -> float:
    """How long ``train`` takes to refuse a missing config on ``tree`` (imports and all): slowest of two."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    times = []
    for _ in range(2):
        start = time.monotonic()
        subprocess.run(
            [sys.executable, "-m", "airimu.cli", "train", "--config", "missing.yaml", "--out", "run"],
            cwd=scratch,
            env=env,
            capture_output=True,
        )
        times.append(time.monotonic() - start)
    return max(times)


def run_case(case: Case, tree: Path, scratch: Path, data: Path, nan_weight: str, startup: float = 0.0) -> Result:
    scratch.mkdir(parents=True)
    if case.name.endswith("10-GB sparse file"):
        subprocess.run(["truncate", "-s", "10G", str(data / "big.csv")], check=True)
    env = dict(os.environ, PYTHONPATH=str(tree), COLUMNS="200")
    env.pop("AIRIMU_DEBUG", None)
    argv = [sys.executable, "-m", "airimu.cli", *case.cli] if case.cli else [sys.executable, "-c", case.code]

    def limits():
        if case.memory_limit:
            import resource

            resource.setrlimit(resource.RLIMIT_AS, (case.memory_limit, case.memory_limit))

    timeout = case.timeout + (startup if case.after_startup else 0.0)
    start = time.monotonic()
    proc = subprocess.Popen(
        argv,
        cwd=scratch,
        env=env,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        errors="replace",
        start_new_session=True,
        preexec_fn=limits,
    )
    try:
        out, err = proc.communicate(timeout=timeout)
        timed_out = False
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        timed_out = True
    seconds = time.monotonic() - start
    for path in case.cleanup:
        path.unlink(missing_ok=True)
    shutil.rmtree(scratch, ignore_errors=True)

    if timed_out:
        outcome = "exit-0" if case.timeout_is_accepted else "hang"
        return Result(outcome, None, f"still running after {timeout:.1f} s (killed)", seconds)
    code = proc.returncode
    if case.code is not None:  # a library snippet
        if SENTINEL in out and "Traceback" not in err:
            result = out.split(SENTINEL, 1)[1].strip()
            kind = result.split(":", 1)[0]
            line = result.splitlines()[0][:200] if result else ""
            if result == "OK":
                return Result("exit-0", code, "no exception", seconds)
            return Result("clean" if kind in CLEAN_TYPES else "traceback", code, line, seconds)
        return Result("traceback", code, last_line(err) or f"exit {code}", seconds)
    line = last_line(err) or last_line(out) or f"exit {code}"
    if "Traceback" in err or code == 1:
        return Result("traceback", code, line, seconds)
    if code == 0:
        return Result("exit-0", code, line, seconds)
    typer_box = "Invalid value" in err or "╭─ Error" in err or err.lstrip().startswith(("Usage:", "Error"))
    if code == 2 and (err.startswith("airimu: error:") or typer_box):
        if case.name.startswith("export-model") and nan_weight not in err:
            return Result("traceback", code, f"does not name the weight: {line}", seconds)
        return Result("clean", code, line, seconds)
    return Result("traceback", code, f"exit {code}: {line}", seconds)  # killed by a signal, other codes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--before", type=Path, required=True, help="the old tree (git worktree of 9afa077)")
    parser.add_argument("--after", type=Path, required=True, help="the new tree (HEAD of main)")
    parser.add_argument("--only", default="", help="run only the cases whose class or name contains this")
    args = parser.parse_args()
    trees = {"BEFORE": args.before.resolve(), "AFTER": args.after.resolve()}

    with tempfile.TemporaryDirectory(prefix="refusal-census-") as tmp:
        tmp = Path(tmp)
        data = tmp / "data"
        data.mkdir()
        for label, tree in trees.items():  # PYTHONPATH beats the editable install: show it
            env = dict(os.environ, PYTHONPATH=str(tree))
            where = subprocess.run(
                [sys.executable, "-c", "import fusion; print(fusion.__file__)"],
                cwd=tmp,
                env=env,
                capture_output=True,
                text=True,
                check=True,
            ).stdout.strip()
            print(f"{label}: {tree} (fusion from {where})")
            assert where.startswith(str(tree)), where
        nan_weight = make_inputs(trees["AFTER"], data)
        startup = {label: startup_seconds(tree, tmp) for label, tree in trees.items()}
        print("start-up (train refusing a missing config): " + ", ".join(f"{k} {v:.1f} s" for k, v in startup.items()))
        cases = [c for c in build_cases(data) if args.only in c.cls or args.only in c.name]
        results: dict[tuple[str, int], Result] = {}
        for i, case in enumerate(cases):
            for label, tree in trees.items():
                r = run_case(case, tree, tmp / "scratch" / label / str(i), data, nan_weight, startup[label])
                results[label, i] = r
                print(
                    f"[{label:6}] {case.cls:15} {case.name:45} {r.outcome:9} {r.seconds:6.1f}s  {r.last_line}",
                    flush=True,
                )

    classes = list(dict.fromkeys(c.cls for c in cases))
    print()
    head = f"{'class':16} {'cases':>5} | {'BEFORE clean/tb/exit0/hang':>27} | {'AFTER clean/tb/exit0/hang':>26}"
    print(head)
    print("-" * len(head))
    totals = {label: dict.fromkeys(OUTCOMES, 0) for label in trees}
    for cls in classes:
        idx = [i for i, c in enumerate(cases) if c.cls == cls]
        cells = []
        for label in trees:
            counts = [sum(results[label, i].outcome == o for i in idx) for o in OUTCOMES]
            for o, n in zip(OUTCOMES, counts, strict=True):
                totals[label][o] += n
            cells.append(" / ".join(f"{n:2}" for n in counts))
        print(f"{cls:16} {len(idx):5} | {cells[0]:>27} | {cells[1]:>26}")
    print("-" * len(head))
    cells = [" / ".join(f"{totals[label][o]:2}" for o in OUTCOMES) for label in trees]
    print(f"{'total':16} {len(cases):5} | {cells[0]:>27} | {cells[1]:>26}")
    print()
    print("AFTER cases that are not clean:")
    bad = [(c, results["AFTER", i]) for i, c in enumerate(cases) if results["AFTER", i].outcome != "clean"]
    for case, r in bad:
        print(f"  [{r.outcome}] {case.cls}: {case.name}: {r.last_line}")
    if not bad:
        print("  (none)")


if __name__ == "__main__":
    main()

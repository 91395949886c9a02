"""Run by .ci/run from outside the checkout with a fresh venv holding only the built wheel and its dependencies:
every shipped config loads from the installed package, and the CLI starts."""

import subprocess
import sys
from pathlib import Path

import airimu_configs

from airimu.experiments.pgo_config import load_pgo_config
from fusion.config import FuseConfig, load_fuse_config
from learned_imu.config import load_config

folder = airimu_configs.FOLDER
assert "site-packages" in folder.parts, f"configs not from the installed wheel: {folder}"
names = airimu_configs.names()
assert {"demo.yaml", "pgo_demo.yaml", "euroc.yaml", "kitti.yaml", "pgo_kitti.yaml", "fuse.yaml"} <= set(names), names
for name in names:
    if name == "fuse.yaml":
        assert load_fuse_config(name) == FuseConfig(), "the shipped fuse.yaml is not FuseConfig's defaults"
        continue
    if name.startswith("fuse_"):  # a fuse config holding only what differs from the defaults
        load_fuse_config(name)
        continue
    config = load_pgo_config(name) if name.startswith("pgo_") else load_config(name)
    if name.startswith("pgo_"):
        assert Path(config.experiment).is_file(), (name, config.experiment)
print(f"{len(names)} shipped configs load from {folder}")
cli = Path(sys.executable).parent / "airimu"
for command in (["--help"], ["demo", "--help"], ["fuse", "--help"]):
    subprocess.run([str(cli), *command], check=True, capture_output=True)
print("airimu starts from the wheel")
from learned_imu.network.checkpoint import load_checkpoint  # noqa: E402
from learned_imu.network.shipped import SHIPPED_DIR, shipped_models  # noqa: E402

assert "site-packages" in SHIPPED_DIR.parts, f"shipped models not from the installed wheel: {SHIPPED_DIR}"
for name in shipped_models():
    load_checkpoint(name)
subprocess.run([str(cli), "models"], check=True, capture_output=True)
print(f"{len(shipped_models())} shipped models load by name from the wheel")

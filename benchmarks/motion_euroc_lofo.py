"""Leave-one-flight-out EuRoC motion models: fusion settings chosen on the training flights, never the test ones.

    python benchmarks/motion_euroc_lofo.py --out runs/euroc-lofo [--only MH_01_easy V1_02_medium] [--threads 1]
    python benchmarks/motion_euroc.py --checkpoint euroc --motion runs/euroc-lofo/MH_01_easy/best.pt \
        --config runs/euroc-lofo/MH_01_easy/config.yaml [fusion flags]   # scores the held-out flight

Flight F's model (``OUT/F``) is ``configs/euroc_motion.yaml`` with F taken out of its training and validation lists
and F alone to evaluate; each of the six training flights in turn. The AirIMU model (``euroc``) saw every one of them,
alike for every setting compared. Runs resume (``airimu train``'s run folders); each takes ~6 min on two CPU cores.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import torch

from learned_imu.config import ExperimentConfig, load_config
from learned_imu.training.experiment import train_run

TEMPLATE = Path(__file__).resolve().parents[1] / "configs" / "euroc_motion.yaml"


def held_out(template: ExperimentConfig, flight: str) -> ExperimentConfig:
    """The template without ``flight`` in training or validation, and with it alone to evaluate."""
    data = template.data
    out = [spec for spec in data.train if Path(spec.path).name == flight]
    if len(out) != 1:
        raise SystemExit(f"{TEMPLATE}: {flight} must be once in data.train")
    train = tuple(spec for spec in data.train if spec not in out)
    val = tuple(spec for spec in data.val if Path(spec.path).name != flight)
    data = dataclasses.replace(data, train=train, val=val, evaluate=tuple(out))
    return dataclasses.replace(template, name=f"{template.name}_without_{flight}", data=data)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="one run folder per held-out flight is made here")
    parser.add_argument("--only", nargs="*", help="these flights (default: all six training flights)")
    parser.add_argument("--threads", type=int, help="torch threads of this process (default: torch's)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    template = load_config(TEMPLATE)
    flights = [Path(spec.path).name for spec in template.data.train]
    for flight in args.only or flights:
        if flight not in flights:
            raise SystemExit(f"--only: {flight} is no training flight of {TEMPLATE} ({', '.join(flights)})")
        summary = train_run(held_out(template, flight), Path(args.out) / flight, progress=False)
        print(f"{flight}: {summary}", flush=True)


if __name__ == "__main__":
    main()

"""Paired comparison of two PGO settings over many GPS seeds, from the exports an ``airimu ablate-pgo`` run wrote.

    python benchmarks/pgo_paired.py --config configs/pgo_demo.yaml --exports airimu-demo/exports --seeds 30

The ablation table reports each setting's mean +- std over seeds; both settings see the same GPS draws, so their
per-seed *difference* has a much smaller spread than either ATE. This prints, per GPS rate, the mean ATE of
``AirIMU + learned cov`` and ``AirIMU + fixed cov``, the mean paired difference with its standard error, and on how
many seeds the learned covariance was lower.
"""

from __future__ import annotations

import argparse

import numpy as np

from airimu.experiments.pgo import ate_m, gps_for
from airimu.experiments.pgo_config import load_pgo_config
from factors import load_export
from fusion.graph import build_graph, solve
from learned_imu.config import load_config
from learned_imu.training.experiment import load_sequences


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", required=True, help="the PGO config the exports were made with")
    parser.add_argument("--exports", required=True, help="folder of <sequence>__airimu_{learned,fixed}.npz")
    parser.add_argument("--seeds", type=int, default=30)
    args = parser.parse_args()
    pgo = load_pgo_config(args.config)
    experiment = load_config(pgo.experiment)
    specs = pgo.sequences or experiment.data.evaluate or experiment.data.val
    for sequence in load_sequences(specs, experiment.data.root):
        learned, fixed = (load_export(f"{args.exports}/{sequence.name}__airimu_{c}.npz") for c in ("learned", "fixed"))
        for rate in pgo.options.gps_hz:
            ates = np.zeros((args.seeds, 2))
            for seed in range(args.seeds):
                fuse, truth = gps_for(sequence, rate, pgo.options.gps_sigma_m, seed)
                for column, export in enumerate((learned, fixed)):
                    graph, values = build_graph(export, fuse, pgo.fusion)
                    solution = solve(graph, values, export.keyframe_t, pgo.fusion)
                    ates[seed, column] = ate_m(solution, truth, fuse if pgo.options.score_span == "gps" else None)
            diff = ates[:, 0] - ates[:, 1]
            print(
                f"{sequence.name} @ {rate} Hz, {args.seeds} seeds: AirIMU + learned {ates[:, 0].mean():.4f} m, "
                f"AirIMU + fixed {ates[:, 1].mean():.4f} m; paired difference {diff.mean():+.4f} +- "
                f"{diff.std(ddof=1) / np.sqrt(args.seeds):.4f} m (standard error); learned lower on "
                f"{int((diff < 0).sum())} of {args.seeds} seeds"
            )


if __name__ == "__main__":
    main()

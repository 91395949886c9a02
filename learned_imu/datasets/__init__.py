"""Dataset readers: one module per format, each returning a checked ``ImuSequence`` (see ``learned_imu.sequence``).

``read_sequence("euroc", path, **options)`` dispatches by name through ``READERS``; each reader's module
docstring states its frames, quaternion order and units. Shared parsing and checks live in the ``_`` modules:
``_table`` (text parsing with line numbers), ``_checks`` (time stamps, gaps, units, frame self-check),
``_assemble`` (ground-truth resampling, velocity from positions, crop and gap policy).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from learned_imu.datasets.broad import read_broad
from learned_imu.datasets.csv import read_csv
from learned_imu.datasets.euroc import read_euroc
from learned_imu.datasets.kitti import read_kitti
from learned_imu.datasets.kitti_raw import read_kitti_raw
from learned_imu.datasets.rosbag import read_rosbag
from learned_imu.sequence import ImuSequence

READERS: dict[str, Callable[..., ImuSequence | list[ImuSequence]]] = {
    "euroc": read_euroc,
    "kitti": read_kitti,
    "kitti_raw": read_kitti_raw,
    "broad": read_broad,
    "rosbag": read_rosbag,
    "csv": read_csv,
}


def read_sequence(dataset: str, path: str | Path | None = None, **options) -> ImuSequence | list[ImuSequence]:
    """Read a sequence with the reader registered as ``dataset`` (a key of ``READERS``).

    ``options`` are the reader's keyword arguments; ``path`` may be None only for ``"kitti"`` (gtsam's copy).
    A list is returned only when the reader was asked to split at gaps (``on_gap="split"``).
    """
    if dataset not in READERS:
        raise ValueError(f"unknown dataset {dataset!r}; known datasets: {', '.join(sorted(READERS))}")
    if path is None and dataset != "kitti":
        raise ValueError(f"dataset {dataset!r} needs a path")
    return READERS[dataset](path, **options)


__all__ = [
    "READERS",
    "read_broad",
    "read_csv",
    "read_euroc",
    "read_kitti",
    "read_kitti_raw",
    "read_rosbag",
    "read_sequence",
]

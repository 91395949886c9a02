"""Models installed with the package: ``--checkpoint euroc`` instead of a path, and the model cards ``airimu models``
prints.

Each shipped model is two files in ``learned_imu/network/shipped_models/``: ``<name>.pt``, a checkpoint of the one
format (``learned_imu.network.checkpoint``) whose trainer state is the weights alone, stored in float16 (the optimiser,
schedule and RNG states of a run are left out: a shipped model is for inference and fine-tuning from, not for
resuming), and ``<name>.yaml``, its card: what it was trained on, the IMU and rate, the metrics it reaches and where
(measured in float32 and with the float16 file), the data's licence. ``load_checkpoint`` takes a shipped name
wherever it takes a path (a file of that name in the working directory wins).
"""

from __future__ import annotations

from pathlib import Path

import yaml

from airimu_core.errors import DataError

SHIPPED_DIR = Path(__file__).resolve().parent / "shipped_models"
CARD_KEYS = ("name", "kind", "summary", "trained_on", "imu", "rate_hz", "metrics", "licence", "command")


def shipped_models() -> dict[str, dict]:
    """Name -> model card (a dict with ``CARD_KEYS``) of every model installed with the package."""
    cards = {}
    for card_path in sorted(SHIPPED_DIR.glob("*.yaml")):
        with open(card_path, encoding="utf-8") as f:
            card = yaml.safe_load(f)
        missing = [key for key in CARD_KEYS if key not in (card or {})]
        if missing:
            raise DataError(card_path, missing[0], "missing from the model card")
        cards[card["name"]] = card
    return cards


def shipped_path(name: str) -> Path | None:
    """The checkpoint of the shipped model ``name``, or None when there is none of that name."""
    path = SHIPPED_DIR / f"{name}.pt"
    return path if "/" not in name and "\\" not in name and path.is_file() else None


def slim(checkpoint, half: bool = True):
    """``checkpoint`` (a ``Checkpoint``) with its trainer state cut to the model weights (float16 with ``half``):
    what ships."""
    import dataclasses

    weights = {
        key: (value.half() if half and value.is_floating_point() else value)
        for key, value in checkpoint.trainer["model"].items()
    }
    return dataclasses.replace(checkpoint, trainer={"model": weights})

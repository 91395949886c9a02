"""Shared fixtures. Real data is read from ``../shared/data`` beside the checkout; a missing folder fails loudly."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    """The real-data folder: ``$AIRIMU_SHARED_DATA`` or ``<repo>/../shared/data``. Raises if it is missing."""
    path = Path(os.environ.get("AIRIMU_SHARED_DATA", REPO.parent / "shared" / "data"))
    if not (path / "README.md").is_file():
        raise FileNotFoundError(
            f"real data folder not found at {path}: tests that prove the method on real data need it "
            "(set AIRIMU_SHARED_DATA or place shared/data beside the checkout)"
        )
    return path


@pytest.fixture(scope="session")
def shared_data() -> Path:
    return shared_data_dir()

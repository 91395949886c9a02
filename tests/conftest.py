"""Shared fixtures. Real data is read from ``../shared/data`` beside the checkout; a missing folder fails loudly.
Builders shared by several test modules live in ``tests.helpers``."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.helpers import shared_data_dir


@pytest.fixture(scope="session")
def shared_data() -> Path:
    return shared_data_dir()

"""Atomic JSON writes: a failed write leaves the previous file intact and no temporary file behind."""

import json

import pytest

from airimu_core.io import write_json_atomic


def test_failed_write_keeps_the_previous_file(tmp_path):
    path = tmp_path / "out.json"
    write_json_atomic(path, {"roe_deg": 1.0})
    with pytest.raises(TypeError):
        write_json_atomic(path, {"bad": object()})  # not JSON-serialisable, fails mid-write
    assert json.loads(path.read_text()) == {"roe_deg": 1.0}
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"]


def test_atomic_writes_get_the_usual_permissions(tmp_path):
    """mkstemp makes 0600 files; a written checkpoint or export must be readable like any other file."""
    import os

    from airimu_core.io import write_json_atomic

    mask = os.umask(0o022)
    try:
        path = write_json_atomic(tmp_path / "out.json", {"a": 1})
    finally:
        os.umask(mask)
    assert path.stat().st_mode & 0o777 == 0o644

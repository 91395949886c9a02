"""Atomic JSON writes: a failed write leaves the previous file intact and no temporary file behind."""

import json

import pytest

from learned_imu.io import write_json_atomic


def test_failed_write_keeps_the_previous_file(tmp_path):
    path = tmp_path / "out.json"
    write_json_atomic(path, {"roe_deg": 1.0})
    with pytest.raises(TypeError):
        write_json_atomic(path, {"bad": object()})  # not JSON-serialisable, fails mid-write
    assert json.loads(path.read_text()) == {"roe_deg": 1.0}
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"]

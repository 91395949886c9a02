"""``airimu fuse`` / ``fusion.fuse``: a log's IMU and real GPS in, a fused trajectory and its files out."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from fusion.cli import app
from fusion.fuse import read_gps_csv
from learned_imu.errors import DataError


def test_fuse_gtsams_kitti_drive_with_its_real_gps(shared_data, tmp_path):
    from evo.tools import file_interface

    out = tmp_path / "fused"
    args = ["fuse", "--dataset", "kitti", "--path", str(shared_data / "kitti_gtsam"), "--gps-every", "10",
            "--keyframes", "1s", "--out", str(out)]  # fmt: skip
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["fused_fixes"] == 47 and summary["reference_fixes"] > 400
    assert summary["rmse_to_gps_m"] < 1.0  # measured 0.604 m against every 1 Hz fix, one in ten fused
    tum = file_interface.read_tum_trajectory_file(str(out / "fused.tum"))
    assert tum.num_poses == summary["keyframes"] == 470
    with np.load(out / "marginals.npz", allow_pickle=False) as marginals:
        assert marginals["pos_cov"].shape == (470, 3, 3)
        assert np.all(np.linalg.eigvalsh(marginals["pos_cov"]) > 0)
    assert (out / "fused.png").read_bytes()[:4] == b"\x89PNG" and (out / "fused.rrd").stat().st_size > 0


def test_reader_options_are_checked_against_the_reader(shared_data, tmp_path):
    drive = shared_data / "kitti_raw" / "2011_10_03_drive_0027.csv"
    args = ["fuse", "--dataset", "kitti_raw", "--path", str(drive), "--reader-option", "on_backwards=drop",
            "--out", str(tmp_path)]  # fmt: skip
    result = CliRunner().invoke(app, args, env={"COLUMNS": "200"})
    assert result.exit_code != 0 and "has no option 'on_backwards'" in result.output
    result = CliRunner().invoke(app, [*args[:5], "--reader-option", "on_backward", "--out", str(tmp_path)])
    assert result.exit_code != 0 and "key=value" in result.output


def test_gps_csv_layouts_and_errors(tmp_path):
    geo = tmp_path / "geo.csv"
    geo.write_text("t,lat,lon,alt,sigma_x,sigma_y,sigma_z\n0.0,49.0,8.4,110.0,1,1,2\n1.0,49.001,8.4,110.0,1,1,2\n")
    fixes = read_gps_csv(geo)
    np.testing.assert_allclose(fixes.pos[0], 0.0, atol=1e-9)
    assert fixes.pos[1][1] == pytest.approx(111.2, abs=0.5) and abs(fixes.pos[1][0]) < 1e-6  # 0.001 deg north
    np.testing.assert_allclose(fixes.sigma[1], [1.0, 1.0, 2.0])
    local = tmp_path / "local.csv"
    local.write_text("time,x,y,z\n0.0,1,2,3\n1.0,2,3,4\n")
    assert np.allclose(read_gps_csv(local, sigma_m=0.5).sigma, 0.5)
    cases = {
        "0.0,1,2,3\n1.0,2,3,4\n": "needs a header",
        "t,a,b,c\n0.0,1,2,3\n1.0,2,3,4\n": "expected columns x, y, z or lat, lon, alt",
        "t,x,y,z\n1.0,1,2,3\n1.0,2,3,4\n": "line 3.*time must increase",
        "t,x,y,z,sigma\n0.0,1,2,3,0.5\n1.0,2,3,4,-1\n": "sigma.*positive",
    }
    for text, message in cases.items():
        bad = tmp_path / "bad.csv"
        bad.write_text(text)
        with pytest.raises(DataError, match=message):
            read_gps_csv(bad)

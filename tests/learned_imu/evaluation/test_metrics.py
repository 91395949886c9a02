"""Metrics against evo on the same trajectories."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from evo.core import metrics as evo_metrics
from evo.core.trajectory import PoseTrajectory3D
from scipy.spatial.transform import Rotation

from learned_imu.evaluation import metrics


def fake_trajectory(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A smooth random trajectory: rotations (n, 3, 3) and positions (n, 3)."""
    rng = np.random.default_rng(seed)
    rotvec = np.cumsum(rng.normal(0, 0.02, (n, 3)), axis=0)
    pos = np.cumsum(rng.normal(0, 0.1, (n, 3)), axis=0)
    return Rotation.from_rotvec(rotvec).as_matrix(), pos


def perturb(rot: np.ndarray, pos: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    noise = Rotation.from_rotvec(rng.normal(0, 0.05, (len(rot), 3))).as_matrix()
    return rot @ noise, pos + rng.normal(0, 0.2, pos.shape) + np.cumsum(rng.normal(0, 0.05, pos.shape), axis=0)


def to_evo(rot: np.ndarray, pos: np.ndarray) -> PoseTrajectory3D:
    quat_xyzw = Rotation.from_matrix(rot).as_quat()
    return PoseTrajectory3D(
        positions_xyz=pos, orientations_quat_wxyz=quat_xyzw[:, [3, 0, 1, 2]], timestamps=np.arange(len(pos)) * 0.1
    )


@pytest.mark.parametrize("align", [False, True])
def test_ate_equals_evo_ape(align):
    rot, pos = fake_trajectory(500, 0)
    est_rot, est_pos = perturb(rot, pos, 1)
    ref, est = to_evo(rot, pos), to_evo(est_rot, est_pos)
    if align:
        est = copy.deepcopy(est)
        est.align(ref, correct_scale=False)
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    expected = ape.get_statistic(evo_metrics.StatisticsType.rmse)
    assert metrics.ate_m(est_pos, pos, align=align) == pytest.approx(expected, rel=1e-9)


def test_window_end_errors_equal_evo_rpe_on_restarted_windows():
    """Our RPE/ROE restart every window from ground truth: per window, evo's RPE over the (start, end) pair of a
    trajectory that starts on ground truth gives the same translation and rotation errors."""
    rot, pos = fake_trajectory(301, 2)
    est_rot, est_pos = perturb(rot, pos, 3)
    length = 30
    starts = np.arange(0, 300, length)
    ends = starts + length
    err = metrics.window_errors(
        est_rot[ends][:, None],
        est_pos[ends][:, None],
        np.zeros((len(ends), 1, 3)),
        rot[ends][:, None],
        pos[ends][:, None],
        np.zeros((len(ends), 1, 3)),
    )
    for k, (s, e) in enumerate(zip(starts, ends, strict=True)):
        ref = to_evo(rot[[s, e]], pos[[s, e]])
        est = to_evo(np.stack([rot[s], est_rot[e]]), np.stack([pos[s], est_pos[e]]))  # restarted at s
        for relation, ours in (
            (evo_metrics.PoseRelation.translation_part, err.end_pos_m[k]),
            (evo_metrics.PoseRelation.rotation_angle_deg, err.end_rot_deg[k]),
        ):
            rpe = evo_metrics.RPE(relation, delta=1, delta_unit=evo_metrics.Unit.frames, all_pairs=False)
            rpe.process_data((ref, est))
            assert ours == pytest.approx(rpe.get_statistic(evo_metrics.StatisticsType.mean), rel=1e-9, abs=1e-9)


def test_umeyama_recovers_a_rigid_motion():
    _, pos = fake_trajectory(100, 4)
    true_rot = Rotation.from_rotvec([0.3, -0.2, 1.0]).as_matrix()
    moved = pos @ true_rot.T + np.array([1.0, -2.0, 3.0])
    rot, trans = metrics.umeyama_alignment(pos, moved)
    np.testing.assert_allclose(rot, true_rot, atol=1e-10)
    np.testing.assert_allclose(trans, [1.0, -2.0, 3.0], atol=1e-9)
    assert metrics.ate_m(pos, moved, align=True) < 1e-9
    with pytest.raises(ValueError, match="N >= 3"):
        metrics.umeyama_alignment(pos[:2], moved[:2])


def test_rotation_angle_is_accurate_for_tiny_and_large_angles():
    for angle in (1e-9, 1e-3, 1.0, 3.1):
        rot = Rotation.from_rotvec([0.0, angle, 0.0]).as_matrix()
        assert metrics.rotation_angle_deg(np.eye(3), rot) == pytest.approx(np.degrees(angle), rel=1e-7)

"""KITTI devkit relative errors on hand-made trajectories with known answers, and against a literal devkit loop."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from airimu_core.errors import InputError
from learned_imu.evaluation.kitti_odometry import KittiErrors, pool, relative_errors, subsample_indices

LENGTHS = (100, 200, 300, 400, 500, 600, 700, 800)
# A straight line of 1000 frames at 1 m per frame (0..999 m): the segment (f, L) ends at the first frame beyond
# f + L, frame f + L + 1, and exists when f + L + 1 <= 999; first frames are 0, 10, 20, ...
STRAIGHT_1000_SEGMENTS = {100: 90, 200: 80, 300: 70, 400: 60, 500: 50, 600: 40, 700: 30, 800: 20}


def yaw(angle_rad) -> np.ndarray:
    """Rotations about z, (..., 3, 3)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    zero, one = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, -s, zero], -1), np.stack([s, c, zero], -1), np.stack([zero, zero, one], -1)], -2)


def straight_line(n: int, frames_per_m: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """n frames along world x, ``frames_per_m`` to a metre, body aligned with world. Whole metres come out exact
    (k / frames_per_m is correctly rounded), so no frame falls a rounding error short of a segment's end."""
    pos = np.zeros((n, 3))
    pos[:, 0] = np.arange(n) / frames_per_m
    return np.tile(np.eye(3), (n, 1, 1)), pos


def rodrigues(rotvec: np.ndarray) -> np.ndarray:
    angle = np.linalg.norm(rotvec, axis=-1, keepdims=True)[..., None]
    axis = rotvec / np.maximum(np.linalg.norm(rotvec, axis=-1, keepdims=True), 1e-300)
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    zero = np.zeros_like(x)
    k = np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2)
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def curvy_drive(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A seeded 3-D drive: heading and pitch wander, ~0.9 m per frame along the body's x axis."""
    rng = np.random.default_rng(seed)
    heading = np.cumsum(rng.normal(0, 0.03, n))
    pitch = 0.05 * np.sin(np.linspace(0, 6, n))
    rot = yaw(heading) @ rodrigues(np.stack([np.zeros(n), pitch, np.zeros(n)], -1))
    step = rot[:, :, 0] * rng.uniform(0.8, 1.0, (n, 1))
    return rot, np.concatenate([np.zeros((1, 3)), np.cumsum(step[:-1], axis=0)])


def hand_mean(per_length: dict[int, float], counts: dict[int, int]) -> float:
    """Mean over segments when every segment of length L has the value per_length[L]."""
    return sum(counts[length] * per_length[length] for length in counts) / sum(counts.values())


def test_identical_trajectories_have_no_error():
    rot, pos = curvy_drive(1200, seed=0)
    errors = relative_errors(rot, pos, rot.copy(), pos.copy())
    assert errors.segments > 0
    assert errors.t_rel_percent == 0.0
    assert errors.r_rel_deg_per_m == 0.0


def test_rigid_change_of_the_estimates_world_changes_nothing():
    rot, pos = curvy_drive(1200, seed=1)
    world = rodrigues(np.array([0.3, -0.2, 1.1]))
    errors = relative_errors(rot, pos, world @ rot, pos @ world.T + np.array([50.0, -20.0, 3.0]))
    assert errors.t_rel_percent == pytest.approx(0.0, abs=1e-9)
    assert errors.r_rel_deg_per_m == pytest.approx(0.0, abs=1e-9)


def test_translation_scaled_by_1_01_gives_one_percent_per_metre_of_segment():
    rot, pos = straight_line(1000)
    errors = relative_errors(rot, pos, rot, 1.01 * pos)
    # each segment spans L + 1 m of ground truth, so its error 0.01 (L + 1) m over L is (1 + 1/L) %
    per_length = {length: 1.0 + 1.0 / length for length in LENGTHS}
    assert dict(zip(LENGTHS, errors.segments_per_length.tolist(), strict=True)) == STRAIGHT_1000_SEGMENTS
    assert errors.segments == 440
    np.testing.assert_allclose(errors.t_rel_percent_per_length, [per_length[length] for length in LENGTHS])
    assert errors.t_rel_percent == pytest.approx(hand_mean(per_length, STRAIGHT_1000_SEGMENTS), rel=1e-12)
    assert errors.t_rel_percent == pytest.approx(1.004359, abs=1e-6)  # 1 + (90/100 + 80/200 + ... + 20/800) / 440
    assert errors.r_rel_deg_per_m == 0.0


def test_constant_heading_drift_per_metre_is_r_rel():
    rate_deg_per_m = 0.005  # the estimate's heading turns 0.5 deg per 100 m driven, relative to ground truth
    rot, pos = straight_line(1000)
    errors = relative_errors(rot, pos, yaw(np.radians(rate_deg_per_m) * pos[:, 0]), pos)
    # the error rotation of a segment from f to f + L + 1 is a yaw of rate x (L + 1) m, divided by L
    per_length = {length: rate_deg_per_m * (length + 1) / length for length in LENGTHS}
    np.testing.assert_allclose(errors.r_rel_deg_per_m_per_length, [per_length[length] for length in LENGTHS])
    expected = hand_mean(per_length, STRAIGHT_1000_SEGMENTS)
    assert errors.r_rel_deg_per_m == pytest.approx(expected, rel=1e-9)
    assert errors.r_rel_deg_per_100m == pytest.approx(100 * expected, rel=1e-9)
    assert errors.r_rel_deg_per_m == pytest.approx(0.005022, abs=1e-6)


@pytest.mark.parametrize(
    ("frames", "first_frames"),
    [
        (251, list(range(0, 141, 10))),  # 0..250 m: f = 150 would need a frame beyond 250 m; there is none
        (252, list(range(0, 151, 10))),  # 0..251 m: frame 251 lies beyond 250 m, so f = 150 counts
    ],
)
def test_segments_start_every_tenth_frame_and_end_strictly_beyond_the_length(frames, first_frames):
    rot, pos = straight_line(frames)
    errors = relative_errors(rot, pos, rot, pos, lengths=(100,), step=10)
    assert errors.segments == len(first_frames)
    assert errors.first_frame.tolist() == first_frames
    assert errors.last_frame.tolist() == [f + 101 for f in first_frames]
    assert errors.length_m.tolist() == [100.0] * len(first_frames)


def devkit_loop(gt_rot, gt_pos, est_rot, est_pos, lengths, step):
    """evaluate_odometry.cpp's calcSequenceErrors transcribed loop by loop, 4 x 4 poses and acos of the trace."""

    def pose(rot, pos):
        out = np.eye(4)
        out[:3, :3], out[:3, 3] = rot, pos
        return out

    gt = [pose(r, p) for r, p in zip(gt_rot, gt_pos, strict=True)]
    est = [pose(r, p) for r, p in zip(est_rot, est_pos, strict=True)]
    dist = [0.0]
    for i in range(1, len(gt)):
        dist.append(dist[i - 1] + float(np.linalg.norm(gt[i][:3, 3] - gt[i - 1][:3, 3])))
    rows = []
    for first in range(0, len(gt), step):
        for length in lengths:
            last = next((i for i in range(first, len(dist)) if dist[i] > dist[first] + length), -1)
            if last == -1:
                continue
            delta_gt = np.linalg.inv(gt[first]) @ gt[last]
            delta_est = np.linalg.inv(est[first]) @ est[last]
            error = np.linalg.inv(delta_est) @ delta_gt
            r_err = np.arccos(max(min(0.5 * (np.trace(error[:3, :3]) - 1.0), 1.0), -1.0))
            t_err = np.linalg.norm(error[:3, 3])
            rows.append((first, last, length, r_err / length, t_err / length))
    return np.array(rows)


def test_matches_a_literal_devkit_loop_on_a_curved_3d_drive():
    gt_rot, gt_pos = curvy_drive(1200, seed=2)
    est_rot, est_pos = curvy_drive(1200, seed=3)  # another drive: large, varied errors
    est_rot, est_pos = est_rot[::-1] @ gt_rot[:1], est_pos * 0.97
    errors = relative_errors(gt_rot, gt_pos, est_rot, est_pos, lengths=(100, 300, 800), step=10)
    rows = devkit_loop(gt_rot, gt_pos, est_rot, est_pos, (100, 300, 800), 10)
    assert errors.segments == len(rows) > 50
    np.testing.assert_array_equal(errors.first_frame, rows[:, 0])
    np.testing.assert_array_equal(errors.last_frame, rows[:, 1])
    np.testing.assert_allclose(errors.t_err_percent, 100 * rows[:, 4], rtol=1e-9)
    np.testing.assert_allclose(errors.r_err_deg_per_m, np.degrees(rows[:, 3]), rtol=1e-7, atol=1e-9)
    assert errors.t_rel_percent == pytest.approx(100 * rows[:, 4].mean(), rel=1e-9)
    assert errors.r_rel_deg_per_m == pytest.approx(np.degrees(rows[:, 3].mean()), rel=1e-7)


def test_pool_weighs_every_segment_the_same():
    rot, pos = straight_line(1000)
    scaled = relative_errors(rot, pos, rot, 1.01 * pos)
    short_rot, short_pos = straight_line(400)
    exact = relative_errors(short_rot, short_pos, short_rot, short_pos)
    pooled = pool([scaled, exact])
    assert isinstance(pooled, KittiErrors)
    assert (
        pooled.segments == scaled.segments + exact.segments == 440 + 30 + 20 + 10
    )  # 0..399 m: 100, 200, 300 m segments
    assert pooled.t_rel_percent == pytest.approx(scaled.t_rel_percent * 440 / pooled.segments, rel=1e-12)
    with pytest.raises(InputError, match="same segment lengths"):
        pool([scaled, relative_errors(rot, pos, rot, pos, lengths=(100,))])


def test_subsampling_100_hz_takes_every_tenth_sample_even_with_jitter():
    t = 1234.5 + 0.01 * np.arange(10_001)
    np.testing.assert_array_equal(subsample_indices(t), np.arange(0, 10_001, 10))
    jitter = np.random.default_rng(4).uniform(-0.002, 0.002, t.shape)
    np.testing.assert_array_equal(subsample_indices(t + jitter), np.arange(0, 10_001, 10))


def test_a_100_hz_trajectory_subsampled_scores_as_its_10_hz_frames():
    t = 0.01 * np.arange(9991)  # 0 .. 99.9 s at 10 m/s: 1000 frames 1 m apart once at 10 Hz
    rot, pos = straight_line(len(t), frames_per_m=10)
    idx = subsample_indices(t)
    errors = relative_errors(rot[idx], pos[idx], rot[idx], 1.01 * pos[idx])
    assert len(idx) == 1000
    assert dict(zip(LENGTHS, errors.segments_per_length.tolist(), strict=True)) == STRAIGHT_1000_SEGMENTS


def _bad_calls():
    rot, pos = straight_line(300)
    nan_rot = rot.copy()
    nan_rot[5, 0, 0] = np.nan
    scaled_rot = rot.copy()
    scaled_rot[3] *= 2.0
    return {
        "est_pos frames": (
            lambda: relative_errors(rot, pos, rot, pos[:-1]),
            r"est_pos: 299 frames, but gt_rot has 300",
        ),
        "est_pos shape": (lambda: relative_errors(rot, pos, rot, pos[:, :2]), r"est_pos: expected shape \(N, 3\)"),
        "gt_rot shape": (lambda: relative_errors(rot[:, :2], pos, rot, pos), r"gt_rot: expected shape \(N, 3, 3\)"),
        "NaN": (lambda: relative_errors(rot, pos, nan_rot, pos), r"est_rot: frame 5 is not finite"),
        "not a rotation": (lambda: relative_errors(scaled_rot, pos, rot, pos), r"gt_rot: frame 3 is not a rotation"),
        "too short": (
            lambda: relative_errors(rot[:51], pos[:51], rot[:51], pos[:51]),
            r"gt_pos: the ground-truth path is 50.0 m long, not longer than the shortest segment length 100 m",
        ),
        "exactly the length": (
            lambda: relative_errors(rot[:101], pos[:101], rot[:101], pos[:101]),
            r"100.0 m long, not longer than the shortest segment length 100 m",
        ),
        "lengths": (lambda: relative_errors(rot, pos, rot, pos, lengths=(100, -5)), r"lengths: expected"),
        "repeated lengths": (lambda: relative_errors(rot, pos, rot, pos, lengths=(100, 100)), r"lengths: each"),
        "step": (lambda: relative_errors(rot, pos, rot, pos, step=0), r"step: expected a positive whole number"),
        "times decrease": (lambda: subsample_indices([0.0, 0.01, 0.005, 0.02]), r"t_s: .*sample 2 does not"),
        "times gap": (
            lambda: subsample_indices(np.r_[0.01 * np.arange(50), 0.8 + 0.01 * np.arange(50)]),
            r"t_s: no sample within 0.05 s of the tick at 0.6000 s \(a gap\)",
        ),
        "times too slow": (lambda: subsample_indices(np.arange(10.0)), r"t_s: median step 1 s is slower than"),
        "rate": (lambda: subsample_indices(np.arange(10.0), rate_hz=0.0), r"rate_hz: expected a positive rate"),
    }


@pytest.mark.parametrize("case", list(_bad_calls()))
def test_bad_input_is_refused_by_name(case):
    call, message = _bad_calls()[case]
    with pytest.raises(InputError, match=message):
        call()


def test_module_imports_without_torch():
    code = "import sys, learned_imu.evaluation.kitti_odometry; print('torch' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "False"

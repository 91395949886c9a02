"""ROS 1 bags, ROS 2 bags (sqlite3 or MCAP storage) and bare ``.mcap`` / ``.db3`` files, via ``rosbags``.

Conventions:

- IMU: ``sensor_msgs/Imu``; ``angular_velocity`` rad/s and ``linear_acceleration`` m/s^2 (specific force: the
  reaction to gravity included, REP 145), in the message's IMU frame. ``orientation`` is ignored.
- Time: ``header.stamp`` in s (``stamp="header"``, default) or the bag's receive time (``stamp="bag"``).
- Optional ground truth from ``gt_topic``: ``nav_msgs/Odometry``, ``geometry_msgs/PoseStamped`` or
  ``geometry_msgs/PoseWithCovarianceStamped``. The pose is taken as the pose of the IMU frame in a z-up world
  frame (REP 103/105: ENU / odom); quaternions (x, y, z, w) -> world <- IMU matrices. No extrinsics are applied:
  the pose's child frame must be the IMU frame. Odometry velocity: ``twist.linear`` is in the child frame
  (nav_msgs definition) and is rotated to the world frame; ``use_twist=False`` (and the PoseStamped types)
  differentiate positions instead (``_assemble``).
- Optional GPS from ``gps_topic``: ``sensor_msgs/NavSatFix`` (REP 145 / sensor_msgs): fixes whose
  ``status.status`` is ``STATUS_NO_FIX`` (-1) are skipped; latitude / longitude (degrees, WGS-84) and altitude (m)
  go to a local east / north / up frame at the first kept fix through pymap3d; the one-sigma per axis is the square
  root of ``position_covariance``'s diagonal (ENU, m^2), or ``gps_sigma`` where the covariance type is
  ``COVARIANCE_TYPE_UNKNOWN`` (0). This local frame is not a ground truth's frame (no alignment is made).
- Gravity ``[0, 0, -gravity]``, default 9.81 m/s^2. IMU cropped to the GT span as in every reader.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from airimu_core.errors import DataError
from airimu_core.sequence import GPS_SIGMA_UNKNOWN_M, GpsFixes, ImuSequence
from learned_imu.datasets._assemble import GtSamples, ReadChecks, build_sequence
from learned_imu.datasets._checks import OnDuplicate, check_timestamps

logger = logging.getLogger(__name__)

GRAVITY = 9.81
IMU_TYPE = "sensor_msgs/msg/Imu"
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped")
NAVSATFIX_TYPE = "sensor_msgs/msg/NavSatFix"
NO_FIX = -1  # sensor_msgs/NavSatStatus STATUS_NO_FIX
STAMPS = ("header", "bag")


def read_rosbag(
    path: str | Path,
    *,
    imu_topic: str | None = None,
    gt_topic: str | None = None,
    stamp: str = "header",
    use_twist: bool = True,
    gravity: float = GRAVITY,
    name: str | None = None,
    checks: ReadChecks = ReadChecks(),
    gps_topic: str | None = None,
    gps_sigma: float = GPS_SIGMA_UNKNOWN_M,
) -> ImuSequence:
    """Read IMU (and optional ground truth and GPS) from a bag (see the module docstring for the conventions).

    Args:
        path: ``.bag`` (ROS 1), a ROS 2 bag folder, or a ``.mcap`` / ``.db3`` file.
        imu_topic: IMU topic; default the first ``sensor_msgs/Imu`` topic in name order.
        gt_topic: ground-truth topic (Odometry / PoseStamped / PoseWithCovarianceStamped); None: no ground truth.
        stamp: ``"header"`` (message stamps) or ``"bag"`` (receive time).
        use_twist: Odometry only; False differentiates positions instead of using the twist.
        gravity: magnitude of gravity, m/s^2 (world z-up).
        name: sequence name (default: the bag's stem).
        checks: duplicates (IMU and ground truth), gaps, crop, self-checks, velocity window
            (``_assemble.ReadChecks``).
        gps_topic: a ``sensor_msgs/NavSatFix`` topic; None: no GPS.
        gps_sigma: one-sigma per axis (m) of fixes whose covariance type is unknown.
    """
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    if stamp not in STAMPS:
        raise ValueError(f"stamp must be one of {STAMPS}, got {stamp!r}")
    path = Path(path)
    if not path.exists():
        raise DataError(path, "path", "bag not found")
    try:
        with AnyReader([path], default_typestore=get_typestore(Stores.LATEST)) as reader:
            types = {topic: info.msgtype for topic, info in reader.topics.items()}
            imu_topic = imu_topic or _default_imu_topic(path, types)
            _require_topic(path, types, imu_topic, (IMU_TYPE,), "imu_topic")
            imu = _collect(reader, imu_topic, stamp, _imu_row, path, "imu_topic")
            gt = None
            candidates = sorted(t for t, m in types.items() if m in (ODOMETRY_TYPE, *POSE_TYPES))
            if gt_topic is None and candidates:
                logger.warning(
                    "%s: read without ground truth, though the bag has pose topics %s (pass gt_topic=...)",
                    path,
                    candidates,
                )
            if gt_topic is not None:
                kind = _require_topic(path, types, gt_topic, (ODOMETRY_TYPE, *POSE_TYPES), "gt_topic")
                row = _odometry_row if kind == ODOMETRY_TYPE else _pose_row
                rows = _collect(reader, gt_topic, stamp, row, path, "gt_topic")
                gt = _ground_truth(path, gt_topic, rows, use_twist and kind == ODOMETRY_TYPE, checks.on_duplicate)
            gps = None
            if gps_topic is not None:
                _require_topic(path, types, gps_topic, (NAVSATFIX_TYPE,), "gps_topic")
                fixes = _collect(reader, gps_topic, stamp, _navsatfix_row, path, "gps_topic")
                gps = _gps(path, gps_topic, fixes, gps_sigma)
    except AnyReaderError as err:
        raise DataError(path, "bag", f"cannot read: {err}") from err
    if stamp == "header" and imu.shape[0] > 1 and np.ptp(imu[:, 0]) == 0:
        raise DataError(path, f"{imu_topic}.stamp", "all header stamps are equal (unset?); pass stamp='bag'")
    keep = check_timestamps(imu[:, 0], path, f"{imu_topic}.stamp", on_duplicate=checks.on_duplicate)
    imu = imu[keep]
    return build_sequence(
        name or path.stem,
        path,
        imu[:, 0],
        imu[:, 1:4],
        imu[:, 4:7],
        np.array([0.0, 0.0, -gravity]),
        gt=gt,
        gps=gps,
        checks=checks,
    )


def _default_imu_topic(path: Path, types: dict[str, str]) -> str:
    topics = sorted(topic for topic, msgtype in types.items() if msgtype == IMU_TYPE)
    if not topics:
        raise DataError(path, "imu_topic", f"no sensor_msgs/Imu topic in the bag (topics: {types})")
    if len(topics) > 1:
        logger.warning("%s: several IMU topics %s, reading %s (pass imu_topic=...)", path, topics, topics[0])
    return topics[0]


def _require_topic(path: Path, types: dict[str, str], topic: str, allowed: tuple[str, ...], option: str) -> str:
    if topic not in types:
        raise DataError(path, option, f"topic {topic!r} not in the bag (topics: {types})")
    if types[topic] not in allowed:
        raise DataError(path, option, f"topic {topic!r} has type {types[topic]}, expected one of {allowed}")
    return types[topic]


def _collect(reader, topic: str, stamp: str, row, path: Path | None = None, option: str = "") -> np.ndarray:
    """(M, k) array of ``[t, *row(msg)]`` for every message on ``topic``, in bag order; with ``path``, a topic
    without messages is a ``DataError`` naming the ``option`` that chose it."""
    connections = [c for c in reader.connections if c.topic == topic]
    out = []
    for connection, bag_ns, raw in reader.messages(connections=connections):
        msg = reader.deserialize(raw, connection.msgtype)
        t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec if stamp == "header" else 1e-9 * bag_ns
        out.append([t, *row(msg)])
    if path is not None and not out:
        raise DataError(path, option, f"topic {topic!r} has no messages")
    return np.asarray(out, dtype=np.float64).reshape(len(out), -1)


def _xyz(v) -> tuple[float, float, float]:
    return v.x, v.y, v.z


def _imu_row(msg) -> list[float]:
    return [*_xyz(msg.angular_velocity), *_xyz(msg.linear_acceleration)]


def _pose_values(pose) -> list[float]:
    q = pose.orientation
    return [*_xyz(pose.position), q.x, q.y, q.z, q.w]


def _pose_row(msg) -> list[float]:
    pose = msg.pose.pose if hasattr(msg.pose, "covariance") else msg.pose
    return _pose_values(pose)


def _odometry_row(msg) -> list[float]:
    return [*_pose_values(msg.pose.pose), *_xyz(msg.twist.twist.linear)]


def _navsatfix_row(msg) -> list[float]:
    cov = np.asarray(msg.position_covariance, dtype=float).reshape(3, 3)
    return [msg.status.status, msg.latitude, msg.longitude, msg.altitude, msg.position_covariance_type, *np.diag(cov)]


def _gps(path: Path, topic: str, rows: np.ndarray, default_sigma: float) -> GpsFixes:
    """Fixes in a local ENU frame at the first kept fix (module docstring)."""
    import pymap3d

    if not (np.isfinite(default_sigma) and default_sigma > 0):
        raise DataError(path, "gps_sigma", f"must be a positive sigma in m, got {default_sigma!r}")
    rows = rows[rows[:, 1] != NO_FIX] if rows.size else rows
    if rows.shape[0] < 2:
        raise DataError(path, topic, f"fewer than 2 NavSatFix messages with a fix ({rows.shape[0]})")
    keep = check_timestamps(rows[:, 0], path, f"{topic}.stamp", on_duplicate="drop")
    rows = rows[keep]
    lat, lon, alt = rows[:, 2], rows[:, 3], rows[:, 4]
    if not np.all(np.isfinite(rows[:, 2:5])) or (np.abs(lat) > 90).any() or (np.abs(lon) > 180).any():
        raise DataError(path, f"{topic}.latitude", "fixes must hold finite latitude / longitude in degrees")
    pos = np.stack(pymap3d.geodetic2enu(lat, lon, alt, lat[0], lon[0], alt[0]), axis=1)
    variance = rows[:, 6:9]
    known = rows[:, 5] > 0  # COVARIANCE_TYPE_UNKNOWN = 0
    sigma = np.where(known[:, None], np.sqrt(np.clip(variance, 0, None)), default_sigma)
    if not np.all(sigma > 0):
        raise DataError(path, f"{topic}.position_covariance", "a fix with a known covariance has a zero variance")
    return GpsFixes(t=rows[:, 0], pos=pos, sigma=sigma)


def _ground_truth(path: Path, topic: str, rows: np.ndarray, use_twist: bool, on_duplicate: OnDuplicate) -> GtSamples:
    if rows.shape[0] < 2:
        raise DataError(path, topic, f"ground truth needs at least 2 messages, got {rows.shape[0]}")
    keep = check_timestamps(rows[:, 0], path, f"{topic}.stamp", on_duplicate=on_duplicate)
    rows = rows[keep]
    gt = GtSamples.from_quaternions(rows[:, 0], rows[:, 4:8], "xyzw", rows[:, 1:4], None, path, f"{topic}.orientation")
    if not use_twist:
        return gt
    vel = np.einsum("nij,nj->ni", gt.rot, rows[:, 8:11])  # child (IMU) frame -> world
    return GtSamples(gt.t, gt.rot, gt.pos, vel, gt.valid & np.isfinite(vel).all(axis=1), path)

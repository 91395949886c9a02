"""Rerun recordings of a fusion run (the only module that imports rerun).

Entity layout, one time line ``time`` in seconds (IMU clock):

- ``world/ground_truth``, ``world/raw``, ``world/airimu``, ``world/fused/<setting>``: ``LineStrips3D``
  trajectories (static: one strip each), world frame, m;
- ``world/gps``: GPS fixes (``Points3D``, static);
- ``world/fused/<setting>/covariance``: ``Ellipsoids3D`` of the marginal position covariance at the keyframes
  (3-sigma, per keyframe on the time line);
- ``imu/gyro/{x,y,z}`` rad/s, ``imu/acc/{x,y,z}`` m/s^2: raw samples; ``correction/gyro/*``, ``correction/acc/*``;
  ``sigma/gyro/*`` rad/s/sqrt(Hz), ``sigma/acc/*`` m/s^2/sqrt(Hz): learned noise (square roots of the densities);
  ``error/position/<setting>`` m: fused position error at the keyframes (``Scalars``).

Whole series go in with ``rr.send_columns``; constants are ``static``. The blueprint opens on the 3-D view beside
the plots. ``airimu view out.rrd`` opens the viewer.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

TIMELINE = "time"
SIGMA_SCALE = 3.0  # ellipsoid half-sizes in standard deviations


@dataclass(frozen=True, eq=False)
class Track:
    """A named trajectory to draw: ``t`` (K,) s, ``pos`` (K, 3) m, world frame; optional ``pos_cov`` (K, 3, 3)."""

    name: str
    t: np.ndarray
    pos: np.ndarray
    pos_cov: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class ImuSeries:
    """Per-sample series: ``t`` (N,) s; raw ``gyro``/``acc``; ``d_gyro``/``d_acc`` corrections; ``gyro_cov``/
    ``acc_cov`` learned densities (rad^2/s, m^2/s^3). All (N, 3), IMU frame."""

    t: np.ndarray
    gyro: np.ndarray
    acc: np.ndarray
    d_gyro: np.ndarray | None = None
    d_acc: np.ndarray | None = None
    gyro_cov: np.ndarray | None = None
    acc_cov: np.ndarray | None = None


def write_recording(
    path: str | Path,
    tracks: list[Track],
    fused: list[Track],
    gps: tuple[np.ndarray, np.ndarray] | None = None,
    imu: ImuSeries | None = None,
    truth: Track | None = None,
    application: str = "airimu",
) -> Path:
    """Write an ``.rrd`` (atomically). ``tracks``: ground truth, raw, AirIMU dead reckoning...; ``fused``: solved
    trajectories (with ``pos_cov`` for ellipsoids); ``gps`` = (t (M,), pos (M, 3)); ``truth`` scores ``fused``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")  # rerun writes the file; rename when complete
    try:
        _record(tmp, application, tracks, fused, gps, imu, truth)
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def _record(tmp: Path, application: str, tracks, fused, gps, imu, truth) -> None:
    rec = rr.RecordingStream(application)
    rec.save(str(tmp))
    rec.send_blueprint(_blueprint(fused), make_active=True)
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    for track in tracks:
        rec.log(f"world/{_slug(track.name)}", rr.LineStrips3D([track.pos]), static=True)
    for track in fused:
        entity = f"world/fused/{_slug(track.name)}"
        rec.log(entity, rr.LineStrips3D([track.pos]), static=True)
        if track.pos_cov is not None:
            _send_ellipsoids(rec, f"{entity}/covariance", track)
        if truth is not None:
            error = np.linalg.norm(track.pos - _at(truth, track.t), axis=1)
            _send_scalars(rec, f"error/position/{_slug(track.name)}", track.t, error[:, None], ("norm",))
    if gps is not None:
        rec.log("world/gps", rr.Points3D(gps[1], radii=0.05), static=True)
    if imu is not None:
        _send_imu(rec, imu)
    rec.flush()
    rec.disconnect()


def _send_imu(rec: rr.RecordingStream, imu: ImuSeries) -> None:
    axes = ("x", "y", "z")
    _send_scalars(rec, "imu/gyro", imu.t, imu.gyro, axes)
    _send_scalars(rec, "imu/acc", imu.t, imu.acc, axes)
    if imu.d_gyro is not None:
        _send_scalars(rec, "correction/gyro", imu.t, imu.d_gyro, axes)
        _send_scalars(rec, "correction/acc", imu.t, imu.d_acc, axes)
    if imu.gyro_cov is not None:
        _send_scalars(rec, "sigma/gyro", imu.t, np.sqrt(imu.gyro_cov), axes)
        _send_scalars(rec, "sigma/acc", imu.t, np.sqrt(imu.acc_cov), axes)


def _send_scalars(rec: rr.RecordingStream, entity: str, t: np.ndarray, values: np.ndarray, names) -> None:
    for i, name in enumerate(names):
        rec.send_columns(
            f"{entity}/{name}",
            indexes=[rr.TimeColumn(TIMELINE, duration=np.asarray(t, dtype=float))],
            columns=rr.Scalars.columns(scalars=np.ascontiguousarray(values[:, i], dtype=float)),
        )


def _send_ellipsoids(rec: rr.RecordingStream, entity: str, track: Track) -> None:
    """One ellipsoid per keyframe: principal axes of the position covariance, ``SIGMA_SCALE`` sigmas."""
    eigval, eigvec = np.linalg.eigh(track.pos_cov)
    eigvec = eigvec * np.sign(np.linalg.det(eigvec))[:, None, None]  # proper rotations
    half_sizes = SIGMA_SCALE * np.sqrt(np.clip(eigval, 0.0, None))
    quat_xyzw = np.array([_quaternion_xyzw(r) for r in eigvec])
    rec.send_columns(
        entity,
        indexes=[rr.TimeColumn(TIMELINE, duration=track.t)],
        columns=rr.Ellipsoids3D.columns(centers=track.pos, half_sizes=half_sizes, quaternions=quat_xyzw),
    )


def _blueprint(fused: list[Track]) -> rrb.Blueprint:
    plots = [
        rrb.TimeSeriesView(origin="/error/position", name="position error (m)"),
        rrb.TimeSeriesView(origin="/imu", name="IMU samples"),
        rrb.TimeSeriesView(origin="/correction", name="corrections"),
        rrb.TimeSeriesView(origin="/sigma", name="learned sigma"),
    ]
    return rrb.Blueprint(
        rrb.Horizontal(rrb.Spatial3DView(origin="/world", name="trajectories"), rrb.Vertical(*plots)),
        collapse_panels=True,
    )


def _at(track: Track, t: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(t, track.t, track.pos[:, i]) for i in range(3)])


def _slug(name: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")


def _quaternion_xyzw(rot: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a rotation matrix (Shepperd's method)."""
    w = np.sqrt(max(0.0, 1.0 + np.trace(rot))) / 2
    if w > 1e-6:
        return np.array([(rot[2, 1] - rot[1, 2]) / (4 * w), (rot[0, 2] - rot[2, 0]) / (4 * w),
                         (rot[1, 0] - rot[0, 1]) / (4 * w), w])  # fmt: skip
    i = int(np.argmax(np.diag(rot)))
    j, k = (i + 1) % 3, (i + 2) % 3
    q = np.zeros(4)
    q[i] = np.sqrt(max(0.0, 1.0 + rot[i, i] - rot[j, j] - rot[k, k])) / 2
    q[j] = (rot[j, i] + rot[i, j]) / (4 * q[i])
    q[k] = (rot[k, i] + rot[i, k]) / (4 * q[i])
    q[3] = (rot[k, j] - rot[j, k]) / (4 * q[i])
    return q / np.linalg.norm(q)

"""KITTI raw OXTS (RT3003 GNSS/INS, the 100 Hz ``oxts/`` stream) with its GNSS/INS solution as ground truth.

Two layouts, read unchanged:

- the official KITTI raw download: a drive folder (``<date>_drive_<nnnn>_extract/``) holding ``oxts/``, or the
  ``oxts/`` folder itself, with ``timestamps.txt`` (``YYYY-MM-DD hh:mm:ss.fffffffff``, one line per packet) and
  ``data/NNNNNNNNNN.txt`` (one line of the 30 OXTS fields per packet, ``dataformat.txt``);
- the shared data's CSV (one ``<drive>.csv`` per drive, ``../shared/data/kitti_raw/README.md``): ``t_s`` (seconds of
  the day), gyro (3), acc (3), ``pos_{x,y,z}_m`` (local east / north / up from the first sample), roll, pitch, yaw,
  ``vel_{east,north,up}_m_s``.

Conventions (verified on the 39 shared drives, README "Conventions"):

- IMU: OXTS ``wx, wy, wz`` [rad/s] and ``ax, ay, az`` [m/s^2] (specific force), body axes x forward, y left, z up.
  The IMU frame here *is* that body frame.
- Attitude: world <- body ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (KITTI's devkit), yaw 0 = east, counter-clockwise.
- Velocity: OXTS ``ve, vn, vu``, world ENU [m/s], taken from the file (not differentiated).
- Position: official layout: ``lat, lon, alt`` (WGS-84, degrees and m) to a local east / north / up frame at the
  first kept packet through ``pymap3d.geodetic2enu``; CSV: its ENU columns as they are (KITTI's devkit computed them
  with a spherical Mercator projection, 0.1-0.2 % off a WGS-84 tangent plane at Karlsruhe).
- World z-up, gravity ``[0, 0, -9.80655]`` m/s^2 by default.
- Time: seconds of the day on the OXTS clock (the clock of GTSAM's KITTI example files).

KITTI's OXTS stream has timestamp anomalies (README "Caveats": gaps of 70 ms to 1.9 s, backward steps next to
replayed packets). By default a backward step is an error naming the file and line; ``on_backward="drop"`` drops
every packet whose stamp is not after the last kept one (the README's rule), ``on_duplicate="drop"`` drops repeated
stamps, and gaps follow ``on_gap`` (``"keep"``: accepted; ``ImuSequence.split_at_gaps`` splits).

GPS (``gps_file``): fixes in GTSAM's ``KittiGps_converted.txt`` layout (``Time,X,Y,Z``, on the OXTS clock), e.g.
GTSAM's 1 Hz fixes of 2011_10_03_drive_0027. GTSAM's conversion put them in a local frame of its own: a per-axis
map of this drive's OXTS position, X = 0.99812 x - 6.83, Y = 0.99809 y - 11.87, Z = z + 0.04 (README caveat 6).
``gps_frame="fit"`` (the default with ground truth) fits that per-axis scale and offset against the ground truth at
the fixes' times and maps the fixes into the ground truth's ENU frame (residual rms 8 / 7 / 0.6 mm on drive 0027;
above ``MAX_GPS_FIT_RMS_M`` the file is refused as not belonging to the drive); ``"as_is"`` keeps the file's frame.
Fixes outside the IMU's time span are dropped.
"""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import numpy as np

from airimu_core.errors import DataError, DependencyError
from airimu_core.sequence import GpsFixes, ImuSequence
from airimu_core.table import read_table
from learned_imu.datasets._assemble import GtSamples, ReadChecks, build_sequence, resolve
from learned_imu.datasets._checks import ON_BACKWARD, check_timestamps, forward_rows  # noqa: F401 (ON_BACKWARD: re-exported)
from learned_imu.datasets.kitti import GPS_SIGMA, read_gps

GRAVITY = 9.80655  # m/s^2, standard gravity (the README's specific-force check used it)
# The OXTS rate channels lag the attitude by ~40 ms (README "Conventions" 5): over the self-check's default 0.05-s
# intervals that alone reads as a 0.35-0.45 relative mismatch on gently turning drives; over 0.3 s it is 0.25 at most
# on the 39 shared drives, while a misread convention still scores about 1.
FRAME_INTERVAL_S = 0.3
CSV_COLUMNS = 16  # t, gyro(3), acc(3), pos(3), rpy(3), vel(3)
OXTS_FIELDS = 30  # KITTI's dataformat.txt
# the OXTS fields (dataformat.txt) that make the CSV's columns after t: wx wy wz, ax ay az, lat lon alt (converted to
# ENU), roll pitch yaw, ve vn vu
OXTS_TO_CSV = [17, 18, 19, 11, 12, 13, 0, 1, 2, 3, 4, 5, 7, 6, 10]
GPS_FRAMES = ("fit", "as_is")
MAX_GPS_FIT_RMS_M = 0.5  # a per-axis scale + offset leaves 8 mm on the drive the fixes belong to
# ReadChecks fields refused unless at their defaults: the ground truth lies on the IMU's own stamps (nothing to crop)
# with its velocity read from the file (nothing to differentiate)
UNUSED_CHECKS = ("crop_to_gt", "vel_window_s")


def read_kitti_raw(
    path: str | Path,
    *,
    ground_truth: bool = True,
    gravity: float = GRAVITY,
    on_backward: str = "error",
    checks: ReadChecks = ReadChecks(),
    gps_file: str | Path | None = None,
    gps_sigma: float = GPS_SIGMA,
    gps_frame: str = "fit",
) -> ImuSequence:
    """Read one KITTI raw drive: the shared CSV, or an official drive / ``oxts`` folder (module docstring).

    Args:
        path: a ``<drive>.csv`` file, or a folder holding ``oxts/`` (or ``timestamps.txt`` and ``data/``).
        ground_truth: False to ignore the GNSS/INS solution.
        gravity: magnitude of gravity, m/s^2 (world z-up, gravity along -z).
        on_backward: ``"error"`` or ``"drop"`` (drop packets whose stamp is not after the last kept one).
        checks: duplicates, gaps and the self-checks (``_assemble.ReadChecks``); ``UNUSED_CHECKS`` are refused
            unless left at their defaults.
        gps_file: GPS fixes (``Time,X,Y,Z``, GTSAM's ``KittiGps_converted.txt``), relative to the drive's folder
            (the CSV's folder, or the drive folder) unless absolute; None: no GPS.
        gps_sigma: one-sigma GPS noise per axis, m (default: GTSAM's example, sqrt(0.07) m).
        gps_frame: ``"fit"`` (map the fixes into the ground truth's frame, module docstring) or ``"as_is"``.
    """
    checks.refuse(UNUSED_CHECKS, "read_kitti_raw", "its ground truth is the IMU's own rows, velocity included")
    if gps_frame not in GPS_FRAMES:
        raise ValueError(f"gps_frame must be one of {GPS_FRAMES}, got {gps_frame!r}")
    path = Path(path)
    if path.is_dir():  # rows in the CSV's column order, lat / lon / alt in the position columns for now
        name, source, rows, line_of = _read_oxts_folder(path)
    elif path.is_file():
        table = read_table(path, delimiter=",", min_columns=CSV_COLUMNS, field="oxts")
        rows = table.data[:, :CSV_COLUMNS]
        table.require_finite(rows, "oxts")
        name, source, line_of = path.stem, path, table.line_of
    else:
        raise DataError(path, "path", "not found (expected a KITTI raw <drive>.csv or a drive folder holding oxts/)")
    monotonic = forward_rows(rows[:, 0], source, "t", on_backward, line_of, "KITTI's replayed OXTS packets")
    unique = check_timestamps(
        rows[monotonic, 0], source, "t", on_duplicate=checks.on_duplicate, line_of=lambda r: line_of(monotonic[r])
    )
    keep = monotonic[unique]
    rows = rows[keep]
    t, gyro, acc, pos, rpy, vel = rows[:, 0], rows[:, 1:4], rows[:, 4:7], rows[:, 7:10], rows[:, 10:13], rows[:, 13:]
    if path.is_dir():  # the local ENU origin is the first kept packet
        pos = _enu(pos, source)
    gt = None
    if ground_truth:
        gt = GtSamples(t, _rotation(*rpy.T), pos, vel, np.ones(len(t), dtype=bool), source)
    gps = None
    if gps_file is not None:
        gps_path = resolve(path.parent if path.is_file() else path, gps_file)
        gps = read_gps(gps_path, gps_sigma)
        if gps_frame == "fit":
            if gt is None:
                raise DataError(gps_path, "gps_frame", "'fit' maps the fixes onto the ground truth: it needs it")
            gps = _fit_gps_frame(gps, gt, gps_path)
    return build_sequence(
        name,
        source,
        t,
        gyro,
        acc,
        np.array([0.0, 0.0, -gravity]),
        gt=gt,
        gps=gps,
        checks=checks,
        line_of=lambda row: line_of(int(keep[row])),
        frame_interval_s=FRAME_INTERVAL_S,
        gps_source=gps_path if gps_file is not None else None,
    )


def _fit_gps_frame(gps: GpsFixes, gt: GtSamples, source: Path) -> GpsFixes:
    """The fixes inside the ground truth's span mapped into its frame: per axis, ``gt = a * fix + b`` fitted by least
    squares over the ground truth interpolated to the fixes' times (module docstring)."""
    inside = (gps.t >= gt.t[0]) & (gps.t <= gt.t[-1])
    if inside.sum() < 3:
        raise DataError(source, "Time", f"{int(inside.sum())} fixes lie within the drive's time span; 3 are needed")
    t, fix = gps.t[inside], gps.pos[inside]
    mapped = np.empty_like(fix)
    for axis in range(3):
        truth = np.interp(t, gt.t, gt.pos[:, axis])
        design = np.column_stack([fix[:, axis], np.ones(len(t))])
        coef = np.linalg.lstsq(design, truth, rcond=None)[0]
        mapped[:, axis] = design @ coef
        rms = float(np.sqrt(np.mean((mapped[:, axis] - truth) ** 2)))
        if not rms <= MAX_GPS_FIT_RMS_M:
            raise DataError(
                source,
                "XYZ"[axis],
                f"a scale and offset leave {rms:.3g} m rms against the drive's ground truth "
                f"(at most {MAX_GPS_FIT_RMS_M} m): these fixes do not belong to this drive",
            )
    return GpsFixes(t, mapped, gps.sigma[inside])


def _rotation(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(N, 3, 3) world <- body, ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("ZYX", np.stack([yaw, pitch, roll], axis=1)).as_matrix()


def _enu(geodetic: np.ndarray, source) -> np.ndarray:
    """(N, 3) local east / north / up positions, m, of (N, 3) lat / lon [deg] / alt [m] about the first row."""
    try:
        import pymap3d
    except ImportError as error:  # a dependency of the package; named for a broken install
        raise DependencyError("reading KITTI's official oxts/ layout needs pymap3d (pip install pymap3d)") from error
    lat, lon, alt = geodetic.T
    if (np.abs(lat) > 90).any() or (np.abs(lon) > 180).any():
        row = int(np.argmax((np.abs(lat) > 90) | (np.abs(lon) > 180)))
        raise DataError(source, "lat/lon", f"packet {row}: ({lat[row]}, {lon[row]}) is not a position in degrees")
    return np.stack(pymap3d.geodetic2enu(lat, lon, alt, lat[0], lon[0], alt[0]), axis=1)


def _read_oxts_folder(folder: Path):
    """(name, source, rows (N, 16) in the CSV's column order with lat / lon / alt as the position, line_of) from an
    official drive or ``oxts`` folder."""
    oxts = folder / "oxts" if (folder / "oxts").is_dir() else folder
    stamps, data = oxts / "timestamps.txt", oxts / "data"
    if not stamps.is_file() or not data.is_dir():
        raise DataError(folder, "path", "no KITTI oxts layout here (expected oxts/timestamps.txt and oxts/data/)")
    lines = [(n, line.strip()) for n, line in enumerate(stamps.read_text().splitlines(), start=1) if line.strip()]
    t = np.empty(len(lines))
    for row, (number, text) in enumerate(lines):
        t[row] = _seconds_of_day(text, stamps, number)
    files = sorted(data.glob("*.txt"))
    if len(files) != len(lines):
        raise DataError(data, "data", f"{len(files)} packet files for {len(lines)} time stamps in {stamps}")
    fields = np.empty((len(files), OXTS_FIELDS))
    for row, file in enumerate(files):
        try:
            values = np.array(file.read_text().split(), dtype=np.float64)
        except ValueError as error:
            raise DataError(file, "oxts", f"not a row of numbers ({error})", line=1) from error
        if values.shape != (OXTS_FIELDS,) or not np.isfinite(values).all():
            raise DataError(file, "oxts", f"expected {OXTS_FIELDS} finite OXTS fields, got {values.size}", line=1)
        fields[row] = values
    name = oxts.parent.name if oxts.name == "oxts" else oxts.name
    rows = np.column_stack([t, fields[:, OXTS_TO_CSV]])
    return name, stamps, rows, lambda row: lines[int(row)][0]


def _seconds_of_day(text: str, source: Path, line: int) -> float:
    """``YYYY-MM-DD hh:mm:ss.fffffffff`` -> seconds since that day's midnight (nanoseconds kept: the fraction is
    parsed as its own number, datetime would truncate it to microseconds)."""
    whole, _, fraction = text.partition(".")
    try:
        clock = datetime.strptime(whole, "%Y-%m-%d %H:%M:%S")
        frac = float(f"0.{fraction}") if fraction else 0.0
    except ValueError as error:
        raise DataError(source, "t", f"not a time stamp 'YYYY-MM-DD hh:mm:ss.f': {text!r}", line=line) from error
    return clock.hour * 3600.0 + clock.minute * 60.0 + clock.second + frac

"""GPS fixes from a CSV file: ``read_gps_csv(path, sigma_m)``.

Comma separated with a header naming the columns: time ``t`` (s, on the IMU clock; also ``time``, ``t_s`` or
``timestamp``), then either ``x, y, z`` (m, a local metric z-up frame) or ``lat, lon, alt`` (degrees, m;
converted to a local east / north / up frame at the first fix through pymap3d); optional per-fix one-sigma
``sigma`` (m, all axes) or ``sigma_x, sigma_y, sigma_z``, else ``sigma_m`` on every axis. GTSAM's
``KittiGps_converted.txt`` (``Time,X,Y,Z``) reads as it is.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from airimu_core.errors import DataError, InputError
from airimu_core.sequence import GPS_SIGMA_UNKNOWN_M, GpsFixes
from airimu_core.table import read_table

ANGLE_UNITS = ("deg", "rad")


def read_gps_csv(
    path: str | Path, sigma_m: float = GPS_SIGMA_UNKNOWN_M, angle_unit: str = "deg", swap: bool = False
) -> GpsFixes:
    """GPS fixes from a CSV (module docstring); ``sigma_m`` (per axis) where the file has no sigma column;
    ``angle_unit``: "deg" (the default) or "rad", how the lat/lon columns are read; ``swap``: read the lat column
    as lon and the lon column as lat (``check_gps_units`` tries it)."""
    if angle_unit not in ANGLE_UNITS:
        raise InputError(f"read_gps_csv: angle_unit must be one of {', '.join(ANGLE_UNITS)}, got {angle_unit!r}")
    path = Path(path)
    table = read_table(path, delimiter=",", min_columns=4, field="gps")
    if not table.header:
        raise DataError(path, "header", "a GPS file needs a header naming its columns (t,x,y,z or t,lat,lon,alt)")
    names = [name.strip().lower() for name in table.header]
    time = next((n for n in ("t", "time", "t_s", "timestamp") if n in names), None)
    if time is None:
        raise DataError(path, "t", f"no time column (t, time, t_s or timestamp) among {table.header}")
    if {"lat", "lon", "alt"} <= set(names):
        layout = ("lat", "lon", "alt")
    elif {"x", "y", "z"} <= set(names):
        layout = ("x", "y", "z")
    else:
        raise DataError(path, "x/y/z", f"expected columns x, y, z or lat, lon, alt; got {table.header}")
    columns = [table.header[names.index(n)] for n in (time, *layout)]
    raw = table.columns(columns, "gps")
    table.require_finite(raw, "gps")
    t, pos = raw[:, 0], raw[:, 1:4]
    if np.any(np.diff(t) <= 0):
        row = int(np.argmax(np.diff(t) <= 0)) + 1
        raise DataError(path, "t", "time must increase from fix to fix", line=table.line_of(row))
    if layout[0] == "lat":
        pos = pos[:, [1, 0, 2]] if swap else pos
        pos = _enu(np.column_stack([np.degrees(pos[:, :2]), pos[:, 2]]) if angle_unit == "rad" else pos, path)
    sigma = _sigmas(table, names, path, sigma_m)
    if {"sigma", "sigma_x"} & set(names):
        _check_sigma_unit(path, "sigma_x/sigma_y/sigma_z" if "sigma_x" in names else "sigma", pos, sigma)
    return GpsFixes(t=t, pos=pos, sigma=sigma)


SIGMA_RATIO = 30.0  # a sigma column this many times the track's own scatter is in another unit


def _check_sigma_unit(path: Path, column: str, pos: np.ndarray, sigma: np.ndarray) -> None:
    """Refuse a sigma column ``SIGMA_RATIO`` (30) times above the scatter of the positions themselves (1.4826 x the MAD
    of their second differences / sqrt(6), per axis, the median over the axes: a fix's noise, plus the motion's
    acceleration over the fix spacing, which only raises it): sigmas in mm or cm read as m leave the GPS out of the
    graph, which then reports itself under-constrained or drifts."""
    if len(pos) < 20:
        return
    second = pos[2:] - 2.0 * pos[1:-1] + pos[:-2]
    scatter = float(np.median(1.4826 * np.median(np.abs(second - np.median(second, axis=0)), axis=0) / np.sqrt(6.0)))
    given = float(np.median(sigma))
    if scatter > 0 and given > SIGMA_RATIO * scatter:
        # the scatter includes the motion's acceleration, so the ratio is a lower bound: 0.05-m fixes with sigmas
        # in mm read 151-216x on KITTI drives, 0.5-m ones 838-923x; the unit is not told apart from it
        raise DataError(
            path,
            column,
            f"the one-sigma column's median {given:.4g} is {given / scatter:.0f}x the scatter of the positions "
            f"themselves ({scatter:.3g} m): in cm or mm, not m? The sigma columns are read as m",
        )


def gps_file_layout(path: str | Path) -> str:
    """ "lat/lon" or "x/y/z": which position columns a GPS CSV has (``read_gps_csv``'s rule)."""
    names = {n.strip().lower() for n in read_table(Path(path), delimiter=",", min_columns=4, field="gps").header}
    return "lat/lon" if {"lat", "lon", "alt"} <= names else "x/y/z"


def _sigmas(table, names: list[str], path: Path, sigma_m: float) -> np.ndarray:
    n = table.data.shape[0]
    if {"sigma_x", "sigma_y", "sigma_z"} <= set(names):
        sigma = table.columns([table.header[names.index(f"sigma_{a}")] for a in "xyz"], "gps")
    elif "sigma" in names:
        sigma = np.repeat(table.columns([table.header[names.index("sigma")]], "gps"), 3, axis=1)
    else:
        sigma = np.full((n, 3), float(sigma_m))
    if not np.all(np.isfinite(sigma) & (sigma > 0)):
        row = int(np.argmax(~np.all(np.isfinite(sigma) & (sigma > 0), axis=1)))
        raise DataError(path, "sigma", "one-sigma GPS noise must be positive (m)", line=table.line_of(row))
    return sigma


def _enu(geodetic: np.ndarray, path: Path) -> np.ndarray:
    import pymap3d

    lat, lon, alt = geodetic.T
    if (np.abs(lat) > 90).any() or (np.abs(lon) > 180).any():
        raise DataError(path, "lat/lon", "not a position in degrees")
    return np.stack(pymap3d.geodetic2enu(lat, lon, alt, lat[0], lon[0], alt[0]), axis=1)

"""A user's own IMU + GPS log in, a fused trajectory out: ``fuse(sequence, gps, model=None, ...)``, behind ``airimu
fuse``.

Stage by stage, reusing the PGO ablation's parts: the model corrects the IMU and predicts its noise (or, without a
model, the raw samples with fixed noise densities); an export holds the keyframe preintegrations, a keyframe at the
IMU sample of every fix (fixes inside a gap of the IMU are not used) or every ``keyframe_s``; ``fusion.graph``
builds the graph (robust GPS factors by default, optional bias states) and Levenberg-Marquardt solves it. The first
state is found from the GPS track (``fusion.initial.aligned_first_state``), never from ground truth: a sequence's
ground truth, if it has one, only scores the result.

GPS files (``read_gps_csv``): comma separated with a header naming the columns: time ``t`` (s, on the IMU clock),
then either ``x, y, z`` (m, a local metric z-up frame) or ``lat, lon, alt`` (degrees, m; converted to a local
east / north / up frame at the first fix through pymap3d); optional per-fix one-sigma ``sigma`` (m, all axes) or
``sigma_x, sigma_y, sigma_z``. GTSAM's ``KittiGps_converted.txt`` (``Time,X,Y,Z``) reads as it is.
"""

from __future__ import annotations

import dataclasses
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from factors import load_export
from fusion.graph import BiasStates, FusionSettings, Solution, build_graph, solve
from fusion.pgo import fixes_on_samples
from learned_imu.datasets.sequence import GpsFixes, ImuSequence
from learned_imu.errors import DataError
from learned_imu.export import export_preintegration, keyframes_every, nearest_samples
from learned_imu.network.model import Correction

DEFAULT_GPS_SIGMA_M = 1.0  # per axis, when the file gives none
# without a model: VINS-Mono's EuRoC setting (sigmas, rad/s/sqrt(Hz) and m/s^2/sqrt(Hz)), a consumer MEMS
DEFAULT_NOISE_DENSITY = (0.004, 0.08)


@dataclass(frozen=True)
class FusedSummary:
    """``summary.json``: the sequence, the keyframes solved, the fixes fused and the reference fixes inside the
    trajectory's span, the position RMSE at those fixes (m) and the ATE against the ground truth (m; None without
    one)."""

    sequence: str
    keyframes: int
    fused_fixes: int
    reference_fixes: int
    rmse_to_gps_m: float
    ate_m: float | None


@dataclass(frozen=True, eq=False)
class Fused:
    """The result: the solution (``.trajectory`` with marginal position covariances), the model's correction of
    the IMU (raw samples with fixed noise without a model), the fixes that were fused, and the sequence."""

    solution: Solution
    correction: Correction
    gps: GpsFixes
    sequence: ImuSequence


def fuse(
    sequence: ImuSequence,
    gps: GpsFixes | None = None,
    model=None,
    settings: FusionSettings | None = None,
    keyframe_s: float | None = None,
    bias: BiasStates | None = None,
    noise_density: tuple[float, float] = DEFAULT_NOISE_DENSITY,
) -> Fused:
    """Fuse ``sequence``'s IMU with ``gps`` (default: the sequence's own fixes); see the module docstring.

    Args:
        model: an ``AirImuNet`` (e.g. ``learned_imu.network.checkpoint.model_from_checkpoint(...)[0]``), or None.
        settings: graph and solver options; default: robust (Huber) GPS factors.
        keyframe_s: a keyframe every this many seconds; None: one at every fix.
        bias: estimate a bias state per keyframe (``fusion.graph.BiasStates``).
        noise_density: (gyro, acc) sigmas without a model.
    """
    from learned_imu.network.inference import correct

    settings = settings or FusionSettings(gps_robust="huber")
    fixes = gps if gps is not None else sequence.gps
    if fixes is None or len(fixes.t) < 2:
        raise DataError(sequence.source or sequence.name, "gps", "fusing needs at least two GPS fixes")
    sequence = dataclasses.replace(sequence, gps=fixes)
    inside = (fixes.t >= sequence.t[0]) & (fixes.t <= sequence.t[-1])
    if inside.sum() < 2:
        raise DataError(sequence.source or sequence.name, "gps", "fewer than two fixes lie within the IMU's time span")
    if keyframe_s is None:
        sequence = fixes_on_samples(sequence)
        index = np.unique(nearest_samples(sequence, sequence.gps.t)[0])
    else:
        index = keyframes_every(sequence, keyframe_s)
    if model is not None:
        correction = correct(model, sequence)
    else:
        import torch

        gyro, acc = torch.as_tensor(sequence.gyro), torch.as_tensor(sequence.acc)
        zero = torch.zeros_like(gyro)
        gyro_cov, acc_cov = (torch.full_like(gyro, s**2) for s in noise_density)
        correction = Correction(gyro, acc, zero, zero, gyro_cov, acc_cov)
    blind = dataclasses.replace(sequence, gt=None)  # the first state from the GPS track, not from ground truth
    with tempfile.TemporaryDirectory() as folder:
        path = export_preintegration(Path(folder) / "fuse.npz", blind, index, correction=correction)
        export = load_export(path)
        used = sequence.gps
        graph, values = build_graph(export, used, settings, bias=bias)
        solution = solve(graph, values, export.keyframe_t, settings)
    return Fused(solution, correction, used, sequence)


def read_gps_csv(path: str | Path, sigma_m: float | None = None) -> GpsFixes:
    """GPS fixes from a CSV (module docstring); ``sigma_m`` (per axis) where the file has no sigma column."""
    from learned_imu.datasets._table import read_table

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
        pos = _enu(pos, path)
    sigma = _sigmas(table, names, path, sigma_m)
    return GpsFixes(t=t, pos=pos, sigma=sigma)


def _sigmas(table, names: list[str], path: Path, sigma_m: float | None) -> np.ndarray:
    n = table.data.shape[0]
    if {"sigma_x", "sigma_y", "sigma_z"} <= set(names):
        sigma = table.columns([table.header[names.index(f"sigma_{a}")] for a in "xyz"], "gps")
    elif "sigma" in names:
        sigma = np.repeat(table.columns([table.header[names.index("sigma")]], "gps"), 3, axis=1)
    else:
        sigma = np.full((n, 3), DEFAULT_GPS_SIGMA_M if sigma_m is None else float(sigma_m))
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


def write_outputs(result: Fused, folder: Path, reference: GpsFixes | None = None) -> tuple[FusedSummary, list[Path]]:
    """``fused.tum`` (TUM, quaternion x y z w, for evo), ``marginals.npz`` (``t`` (K,), ``pos`` (K, 3) m,
    ``pos_cov`` (K, 3, 3) m^2, world frame), ``fused.rrd``, ``fused.png`` and ``summary.json`` (RMSE against the
    ``reference`` fixes, default the fused ones, and the ATE against the ground truth where the sequence has one:
    meaningful only when the GPS is in the ground truth's frame),
    each written atomically. Returns the summary and the paths."""
    from fusion.figures import plot
    from fusion.graph import with_marginals
    from fusion.pgo import SequenceResult, record
    from learned_imu.io import atomic_file, output_folder, write_json_atomic

    output_folder(folder)
    trajectory = with_marginals(result.solution)
    written = [trajectory.write_tum(folder / "fused.tum")]
    with atomic_file(folder / "marginals.npz", "wb") as f:
        np.savez(f, t=trajectory.t, pos=trajectory.pos, pos_cov=trajectory.pos_cov)
    written.append(folder / "marginals.npz")
    view = SequenceResult(result.sequence, result.correction, [], {"fused": (result.solution, result.gps)})
    written += [record(view, folder / "fused.rrd"), plot(view, folder / "fused.png")]
    reference = reference if reference is not None else result.gps
    inside = (reference.t >= trajectory.t[0]) & (reference.t <= trajectory.t[-1])
    err = trajectory.position_at(reference.t[inside]) - reference.pos[inside]
    rmse = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    ate = None
    gt = result.sequence.gt
    if gt is not None:
        keep = gt.valid & (result.sequence.t >= trajectory.t[0]) & (result.sequence.t <= trajectory.t[-1])
        err = trajectory.position_at(result.sequence.t[keep]) - gt.pos[keep]
        ate = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    summary = FusedSummary(result.sequence.name, len(trajectory.t), len(result.gps.t), int(inside.sum()), rmse, ate)
    written.append(write_json_atomic(folder / "summary.json", dataclasses.asdict(summary)))
    return summary, written

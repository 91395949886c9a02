"""Online IMU + GPS fusion: samples and fixes go in as they arrive; the learned pose graph is solved incrementally.

Per block of IMU samples (``OnlineFusion.add_imu``), as ``fusion.graph.build_graph`` but one keyframe at a time:
buffer the samples; decide keyframes (the first sample, then the first at least ``keyframe_s`` after the grid's
previous one, with half a sample period of tolerance: ``export.keyframes_every`` for uniform rates; and one at the
sample of each fix, ``export.merge_keyframes``); once an interval is complete,
correct it with the model in streaming mode (``AirImuNet.stream``, carried GRU state: what a one-pass
``correct_sequence`` gives) or take the raw samples with fixed noise; preintegrate it with GTSAM's own
preintegration and the per-sample learned noise (``factors.learned_pim``: the export's ``learned_imu.preintegrate``
route pays torch's call overhead per interval, this one a fraction of it; the two agree to GTSAM's tangent-vs-manifold
discretisation, well inside the 1 cm online-vs-batch check); wrap it in GTSAM's C++ ``ImuFactor``, predict
the new keyframe through it, and add it with its GPS factors to ``gtsam.ISAM2`` (or an
``IncrementalFixedLagSmoother``). GPS fixes attach to the nearest keyframe (the earlier on a tie) without
interpolation; each fix gets a keyframe of its own at its nearest sample (so that it constrains the state at its
own time) when it is added before a keyframe past its time entered the graph: add each fix before the IMU samples
after it (``keyframe_s`` then adds keyframes between the fixes).

Keys: ``X(k)`` (``Pose3`` world <- IMU), ``V(k)`` (world velocity, m/s), ``B(k)``. Only C++ factors enter the
smoother (a Python ``CustomFactor`` gets a copy of all values per call), except, with a motion model, one
``factors.MotionFactor`` per keyframe (ISAM2 re-linearises few factors per update). The samples are corrected, so each
``ImuFactor`` sees a zero bias as in the batch graph, but through its own ``B(k)`` held by a ``NonlinearEquality``
rather than one shared ``B(0)``: a key in every factor sits in ISAM2's root clique and updates touch all factors,
so the update time grows with the whole trajectory (BENCHMARKS.md, "Design measurements").
The solution is the same (the bias is exactly zero either way); ISAM2 eliminates the constraint's clique by QR
(``EliminatePreferCholesky``), so no tight prior is needed. Latency: BENCHMARKS.md ("Online fusion").

With ``bias=BiasStates(...)`` (``factor="between"``, GTSAM's ``IMUKittiExampleGPS.py`` structure) each ``B(k)`` is
estimated: a prior on ``B(0)``, the random walk ``B(k) -> B(k+1)`` (``BiasStates.walk_sigmas``), and each interval
preintegrated around the latest estimate of its bias (GTSAM's ``biasHat``). With the ``"isam2"`` smoother the
re-linearisation of ``factors.solve_relinearised`` is built in: after every update, each interval whose bias estimate
has moved more than ``FuseConfig.online.bias_relinearize_tol`` (rad/s and m/s^2) from the bias it was preintegrated
around is preintegrated again around the estimate, and its ``ImuFactor`` swapped in the smoother (``ISAM2.update``'s
``removeFactorIndices``); ``flush`` repeats this until no bias moves more than the tolerance. The result equals
GTSAM's own graph preintegrated at the converged biases (``tests/fusion/test_online_bias.py``: 1e-6 m). This keeps
every interval's samples (13 floats a sample). The fixed-lag smoother estimates the biases too, each interval
preintegrated around the bias estimate at its arrival, first-order after that (its factor indices are not exposed).
"""

from __future__ import annotations

import bisect
import logging
from dataclasses import dataclass

import gtsam
import numpy as np

from airimu_core.errors import AirImuError, InputError, real_array
from airimu_core.motion import BodyVelocities
from airimu_core.sequence import GpsFixes
from factors import GpsFactor, MotionFactor, gps_noise, learned_pim
from factors.noise import noise_mismatch
from fusion.align import MOVE_M, Aligner, Alignment
from fusion.config import FuseConfig
from fusion.graph import Trajectory
from fusion.initial import first_state, priors_on_first

log = logging.getLogger(__name__)
X, V, B = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.V, gtsam.symbol_shorthand.B
RATE_CHECK_SAMPLES = 20  # samples seen before the stream's rate is compared with the model's training rate
CONVERGE_ROUNDS = 20  # flush's re-linearisation rounds at most (bias states with ISAM2)
NOISE_CHECK_SAMPLES = 400  # raw samples seen before given densities are compared with the stream's white noise
UNIT_CHECK_S = 120.0  # the gyro's unit checked once against gravity and a car's turns, this long into the stream


@dataclass(eq=False)
class _Interval:
    """One interval's samples (gyro, acc, dt, gyro_cov, acc_cov), the bias its factor was preintegrated around and
    the factor's index in ISAM2: what re-linearisation needs."""

    k: int  # from keyframe k to k + 1
    samples: tuple[np.ndarray, ...]
    bias_hat: gtsam.imuBias.ConstantBias
    index: int


@dataclass(frozen=True, eq=False)
class OnlineState:
    """The estimate at the latest keyframe in the graph.

    ``t`` s (IMU clock); ``rot`` (3, 3) world <- IMU; ``pos`` (3,) m and ``vel`` (3,) m/s, world frame.
    ``pose_cov`` (6, 6): marginal covariance in GTSAM's ``Pose3`` tangent at the estimate, [rotation (rad),
    translation (m)], both in the IMU frame (perturbation ``R Exp(d_rot)``, ``p + R d_pos``); ``vel_cov`` (3, 3):
    marginal velocity covariance, m^2/s^2, world frame.
    """

    t: float
    rot: np.ndarray
    pos: np.ndarray
    vel: np.ndarray
    pose_cov: np.ndarray
    vel_cov: np.ndarray

    @property
    def pos_cov(self) -> np.ndarray:
        """(3, 3) marginal position covariance, m^2, world frame."""
        return self.rot @ self.pose_cov[3:, 3:] @ self.rot.T


class OnlineFusion:
    """Incremental IMU + GPS fusion with learned IMU factors (see the module docstring).

    Args:
        model: an ``AirImuNet`` in eval mode, or None for the raw samples with the config's noise densities.
        gravity: (3,) gravity vector in the world frame, m/s^2.
        initial_state: ``gtsam.NavState`` (pose world <- IMU, world velocity m/s) at the first IMU sample: the prior's
            mean; or None: found from the stream (``fusion.align``: roll and pitch from gravity, the raw gyro's bias
            from a still start, heading by search once the GPS track shows the platform accelerating), never from
            ground truth. Until then nothing enters the graph (``current_state`` says what it waits for); then
            everything received so far is replayed, and ``alignment`` holds what was found.
        config: ``fusion.config.FuseConfig``, the batch fusion's settings (default ``FuseConfig()``, as
            ``configs/fuse.yaml``): ``online`` (keyframe interval, smoother, lag, ISAM2's relinearisation threshold,
            the bias re-linearisation tolerance), the noise densities without a model (densities other than the
            defaults are compared with the stream's own white noise once ``NOISE_CHECK_SAMPLES`` samples are in, and
            warned about 100x under or 10x over it), ``graph`` (the prior on the first state, the GPS robust loss and
            lever arm), and the bias states (``estimate_bias``; ``bias.factor`` must be ``"between"``), ``motion``
            (``cov_scale``).
        motion_model: a ``MotionNet`` in eval mode, or None: a learned body-frame velocity factor
            (``factors.MotionFactor``) at every keyframe, from the model streamed over the raw samples with the
            attitude the graph predicts for them (the last keyframe's estimate carried by the corrected gyro; never
            ground truth). The factor of keyframe k holds the model's last output before k's sample (at most one
            block, 9 samples, earlier: choose ``keyframe_s`` a whole number of blocks to make them coincide).
            Where the keyframe's predicted speed exceeds the model's speed envelope (``motion.speed_envelope``), the
            factor's along-track axis is left to the IMU; ``beyond_envelope`` counts those factors.
    """

    def __init__(self, model, gravity, initial_state, config: FuseConfig | None = None, motion_model=None):
        config = config or FuseConfig()
        if not isinstance(config, FuseConfig):
            raise InputError(f"OnlineFusion: config must be a fusion.config.FuseConfig, got {type(config).__name__}")
        online, graph, bias = config.online, config.graph, config.bias_states
        if model is not None and model.training:
            raise InputError("OnlineFusion: call model.eval() first (streaming needs eval mode)")
        if model is not None and getattr(model, "removes_gravity", False):
            raise InputError(
                "OnlineFusion: the model was trained with remove_gravity (gravity in the IMU frame from "
                "ground truth), which a live stream does not have"
            )
        if motion_model is not None and motion_model.training:
            raise InputError("OnlineFusion: call motion_model.eval() first (streaming needs eval mode)")
        if config.imu_gaps != "hold":
            raise InputError(
                f"OnlineFusion: imu_gaps {config.imu_gaps!r} is batch only (airimu fuse without --online); a stream "
                "integrates a gap with the sample before it held: set imu_gaps: hold"
            )
        if config.imu_delay_s:
            raise InputError(
                "OnlineFusion: imu_delay_s is batch only (airimu fuse without --online); a stream stamps its samples "
                "itself: give add_imu the times less the delay"
            )
        for name, what in (("mount_sigma_rad", "a mounting-rotation state"), ("scale_sigma", "speed-scale states")):
            if motion_model is not None and getattr(config.motion, name) is not None:
                raise InputError(
                    f"OnlineFusion: motion.{name} ({what}) is batch only (airimu fuse without --online); set it to null"
                )
        self._model, self._keyframe_s, self._lag_s = model, online.keyframe_s, online.lag_s
        self._motion, self._motion_scale = motion_model, np.asarray(config.motion.cov_scale, dtype=float)
        self._speed_limit = config.motion.speed_limit_m_s(motion_model) if motion_model is not None else None
        self.beyond_envelope = 0  # motion factors whose along-track axis the speed envelope left to the IMU
        self._motion_stream = motion_model.initial_state(1) if motion_model is not None else None
        self._motion_raw = np.zeros((0, 6))  # raw [gyro, acc] from sample self._base on, for the motion model
        self._motion_outputs = 0  # outputs of the motion model so far: output j ends at sample (j + 1) block - 1
        self._last_motion: tuple[int, np.ndarray, np.ndarray] | None = None  # (end sample, v_body, variance)
        self._gravity = _vector("gravity", gravity)
        self._first = None if initial_state is None else first_state(initial_state, "OnlineFusion")
        self.alignment: Alignment | None = None  # the first state found from the stream (initial_state=None)
        self._pending_t, self._pending_raw = np.zeros(0), np.zeros((0, 6))  # samples before the alignment
        self._pending_fixes: list[tuple[float, np.ndarray, np.ndarray]] = []  # fixes before the alignment
        self._align_tried = 0  # fixes at the last alignment attempt
        self._aligner = Aligner(self._gravity, config.noise_density) if initial_state is None else None
        self._gyro_offset = np.zeros(3)  # the still start's gyro bias, taken out of the raw samples (no model)
        self._prior_sigmas = (graph.prior_rot_sigma_rad, graph.prior_pos_sigma_m, graph.prior_vel_sigma_m_s)
        self._density = np.repeat(np.square(config.noise_density), 3)  # [gyro x3, acc x3], sigma^2
        self._gps_robust, self._lever_arm_m = graph.gps_robust, _vector("lever_arm_m", graph.lever_arm_m)
        if bias is not None and bias.factor != "between":
            raise InputError(
                f"OnlineFusion: bias.factor must be 'between' (an ImuFactor and the random walk between "
                f"bias keys, as IMUKittiExampleGPS.py), got {bias.factor!r}"
            )
        relinearise_tol, relinearize_threshold = online.bias_relinearize_tol, online.relinearize_threshold
        smoother = online.smoother
        given = not config.noise_is_default
        self._bias, self._relinearise_tol = bias, float(relinearise_tol)
        self._intervals: list[_Interval] = []  # bias states with ISAM2: every interval, for re-linearisation
        self._samples_seen = 0  # samples in the graph's intervals (the cumulative bias walk counts them)
        self.reintegrated = 0  # intervals preintegrated again around a moved bias estimate, so far
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(float(relinearize_threshold))
        params.relinearizeSkip = 1
        params.enablePartialRelinearizationCheck = True
        if bias is not None:  # tight IMU factors beside a loose bias prior: Cholesky finds the system indeterminate
            params.setFactorization("QR")  # (as with GTSAM's IMUKittiExampleGPS.py, BENCHMARKS.md)
        self._fixed_lag = smoother == "fixed_lag"
        self._smoother = (
            gtsam.IncrementalFixedLagSmoother(self._lag_s, params) if self._fixed_lag else gtsam.ISAM2(params)
        )
        self._stream = model.initial_state(1) if model is not None else None
        self._t = np.zeros(0)  # sample times from the last keyframe in the graph on (sample index self._base)
        self._samples = np.zeros((0, 12))  # corrected [gyro, acc, gyro_cov, acc_cov] from the same sample on
        self._raw = np.zeros((0, 6))  # raw [gyro, acc] not yet given to the model
        self._base = 0
        self._kf_t: list[float] = []  # decided keyframe times, s
        self._kf_index: list[int] = []  # their sample indices
        self._in_graph = 0  # keyframes 0 .. _in_graph - 1 are in the smoother
        self._waiting: list[tuple[float, np.ndarray, gtsam.noiseModel.Base]] = []  # fixes after the last keyframe
        self._gps_for: dict[int, list[GpsFactor]] = {}  # fixes of keyframes not in the graph yet
        self._frozen: dict[int, tuple[gtsam.Pose3, np.ndarray]] = {}  # keyframes that left the fixed-lag window
        self._flushed = False
        self._rate_checked = False
        self._noise_sample = (np.zeros(0), np.zeros((0, 6))) if model is None and given else None  # _check_noise
        self._unit_sample: list[tuple[np.ndarray, np.ndarray]] | None = []  # _check_units (None: done)
        self.unused_fixes: tuple[float, ...] = ()  # times of the fixes flush() could not use
        self._grid_t = 0.0  # the time of the keyframe grid's latest point (fixes' keyframes do not move it)
        self._late_warned = False  # a fix applied away from its own time (it came after its sample left the buffer)

    @property
    def keyframes(self) -> int:
        """Number of keyframes in the graph."""
        return self._in_graph

    @property
    def smoother(self) -> gtsam.ISAM2 | gtsam.IncrementalFixedLagSmoother:
        """The GTSAM smoother, for inspection (factors added to it directly bypass this class's bookkeeping)."""
        return self._smoother

    def add_imu(self, t, gyro, acc) -> int:
        """Add one sample (``t`` float, ``gyro``/``acc`` (3,)) or a block (``t`` (M,), (M, 3)): rad/s and m/s^2,
        raw, IMU frame, times strictly increasing. Returns the number of keyframes this added to the graph."""
        t, raw = self._check_samples(t, gyro, acc)
        if self._first is None:
            return self._wait_for_alignment(t, raw)
        first = self._base + len(self._t)  # sample index of t[0]
        self._t = np.concatenate([self._t, t])
        for i, ti in enumerate(t):
            if not self._kf_t:
                self._decide_keyframe(ti, first + i)
                self._grid_t = float(ti)
                self._start()
                continue
            half = 0.5 * (ti - self._t[first + i - 1 - self._base])
            while self._waiting and self._waiting[0][0] <= ti + half:  # a fix whose nearest sample this is
                fix = self._waiting.pop(0)
                if first + i - self._kf_index[-1] >= 2:  # its own keyframe (an interval needs two samples)
                    self._decide_keyframe(ti, first + i)
                self._attach(self._nearest_keyframe(fix[0]), fix)
            if ti - self._grid_t >= self._keyframe_s - half:  # the grid between the fixes' keyframes
                self._grid_t = float(ti)
                if first + i - self._kf_index[-1] >= 2:
                    self._decide_keyframe(ti, first + i)
        if self._motion is not None:
            self._motion_raw = np.concatenate([self._motion_raw, raw])
        if self._model is None:
            raw = raw - np.concatenate([self._gyro_offset, np.zeros(3)])
            self._samples = np.concatenate([self._samples, np.hstack([raw, np.broadcast_to(self._density, raw.shape)])])
        else:
            self._raw = np.concatenate([self._raw, raw])
        return self._close_keyframes()

    def add_gps(self, t: float, pos_m, sigma_m) -> bool:
        """Add a GPS fix: time ``t`` s (IMU clock), antenna position ``pos_m`` (3,) m in the world frame, one-sigma
        noise ``sigma_m`` m (float or (3,), a standard deviation). Returns True if the graph was updated now,
        False if the fix waits for its keyframe (or, fixed-lag only, was dropped as older than the window)."""
        t, pos = real_array(t, "add_gps: t"), _vector("GPS pos_m", pos_m)
        sigma = real_array(sigma_m, "add_gps: sigma_m")
        if t.shape != () or sigma.shape not in ((), (3,)):
            raise InputError(
                f"add_gps: need a time (a float) and sigma_m as a float or (3,), got shapes {t.shape} and {sigma.shape}"
            )
        t, sigma = float(t), np.broadcast_to(sigma, (3,))
        if not np.isfinite(t) or not np.all(np.isfinite(sigma)) or np.any(sigma <= 0):
            raise InputError(f"add_gps: need a finite time and positive, finite sigma_m, got t={t}, sigma_m={sigma_m}")
        if self._first is None:  # no start yet: kept for the alignment, then replayed
            if not len(self._pending_t) or t < self._pending_t[0]:
                first = f"{self._pending_t[0]} s" if len(self._pending_t) else "none yet"
                raise InputError(f"add_gps: fix at t={t} s precedes the first IMU sample ({first})")
            bisect.insort(self._pending_fixes, (t, pos, np.array(sigma)), key=lambda f: f[0])
            return False
        if not self._kf_t or t < self._kf_t[0]:
            first = f"{self._kf_t[0]} s" if self._kf_t else "none yet"
            raise InputError(f"add_gps: fix at t={t} s precedes the first IMU sample ({first})")
        fix = (t, pos, gps_noise(sigma, self._gps_robust))
        if len(self._t) < 2 or t > self._t[-1] + 0.5 * (self._t[-1] - self._t[-2]):  # its sample is still to come
            bisect.insort(self._waiting, fix, key=lambda f: f[0])
            return False
        return self._attach(self._keyframe_for_fix(t), fix)

    def flush(self) -> int:
        """End of the stream: the model's last partial block is padded with the last sample (as
        ``correct_sequence`` does), completed keyframes are added, and waiting fixes within half an interval of the
        last keyframe attach to it; later ones are not used, logged as a warning and kept in ``unused_fixes``
        (their times, s). Further samples are refused. Returns the number of keyframes added."""
        if self._first is None and not self._flushed:
            self._align(force=True)
            if self._first is None:
                self._flushed = True
                self.unused_fixes = tuple(f[0] for f in self._pending_fixes)
                log.warning(
                    "OnlineFusion.flush: no start was found (initial_state=None needs two GPS fixes within the IMU "
                    "samples; %d came): nothing was fused",
                    len(self._pending_fixes),
                )
                return 0
        if self._model is not None and not self._flushed:
            self._correct(flush=True)  # also the samples the model holds back for an incomplete block
        self._flushed = True
        added = self._close_keyframes()
        late = []
        for fix in self._waiting:
            if fix[0] - self._kf_t[-1] <= 0.5 * self._keyframe_s:
                self._attach(len(self._kf_t) - 1, fix)
            else:
                late.append(fix[0])
        self._waiting = []
        if self._bias is not None and not self._fixed_lag:
            self._converge()
        self.unused_fixes = tuple(late)
        if late:
            log.warning(
                "OnlineFusion.flush: %d GPS fix(es) at t = %s s lie more than half a keyframe interval after the last "
                "IMU sample (%s s) and were not used: a GPS clock ahead of the IMU's, or the stream cut short?",
                len(late),
                ", ".join(f"{t:.3f}" for t in late[:5]) + (" ..." if len(late) > 5 else ""),
                f"{self._t[-1]:.3f}",
            )
        return added

    def current_state(self) -> OnlineState:
        """The latest keyframe's estimate and marginal covariances (see ``OnlineState``)."""
        if not self._in_graph:
            if self._first is None and len(self._pending_t):
                raise AirImuError(
                    f"OnlineFusion.current_state: no start yet (initial_state=None): waiting for the GPS track to move "
                    f"{MOVE_M:g} m with a decisive heading ({len(self._pending_fixes)} fixes, "
                    f"{self._pending_t[-1] - self._pending_t[0]:.1f} s of IMU so far)"
                )
            raise AirImuError("OnlineFusion.current_state: no IMU sample yet")
        k = self._in_graph - 1
        pose, vel = self._estimate(k)
        pose_cov, vel_cov = self._smoother.marginalCovariance(X(k)), self._smoother.marginalCovariance(V(k))
        rot = pose.rotation().matrix()
        return OnlineState(self._kf_t[k], rot, pose.translation(), np.asarray(vel), pose_cov, vel_cov)

    def trajectory(self) -> Trajectory:
        """All keyframes in the graph at their current estimates (fixed-lag: older ones as they left the window)."""
        values = self._smoother.calculateEstimate()
        states = [self._frozen.get(k) or (values.atPose3(X(k)), values.atVector(V(k))) for k in range(self._in_graph)]
        return Trajectory(
            t=np.array(self._kf_t[: self._in_graph]),
            rot=np.array([p.rotation().matrix() for p, _ in states]).reshape(-1, 3, 3),
            pos=np.array([p.translation() for p, _ in states]).reshape(-1, 3),
            vel=np.array([v for _, v in states]).reshape(-1, 3),
        )

    def _wait_for_alignment(self, t: np.ndarray, raw: np.ndarray) -> int:
        """Without a first state: keep the samples; once a fix has come since the last try, try the alignment
        (``fusion.align``). Returns the keyframes the replay added."""
        self._pending_t = np.concatenate([self._pending_t, t])
        self._pending_raw = np.concatenate([self._pending_raw, raw])
        if len(self._pending_fixes) > self._align_tried and self._pending_fixes[-1][0] <= self._pending_t[-1]:
            return self._align(force=False)
        return 0

    def _align(self, force: bool) -> int:
        """The first state from the samples and fixes so far (``fusion.align.align``); found, everything so far is
        replayed through the graph (each fix before the samples after it). Returns the keyframes added."""
        if len(self._pending_t) < 2:
            return 0
        self._align_tried = len(self._pending_fixes)
        fixes = GpsFixes(
            np.array([f[0] for f in self._pending_fixes]),
            np.array([f[1] for f in self._pending_fixes]).reshape(-1, 3),
            np.array([f[2] for f in self._pending_fixes]).reshape(-1, 3),
        )
        raw = self._pending_raw
        found = self._aligner.update(self._pending_t, raw[:, :3], raw[:, 3:], fixes, force)
        if found is None:
            return 0
        if found.forced:
            log.warning(
                "OnlineFusion: first state taken after %.1f s of IMU with a heading sigma of %.1f deg and a tilt sigma "
                "of %.1f deg: the platform had not accelerated (or turned) enough to show them; the first minutes "
                "may carry that error",
                found.waited_s,
                np.degrees(found.yaw_sigma_rad),
                np.degrees(found.tilt_sigma_rad),
            )
        self.alignment = found
        self._first = (found.state.pose(), np.asarray(found.state.velocity()))
        if self._model is None and found.still is not None:
            self._gyro_offset = found.still.gyro_bias
        t, raw, fixes = self._pending_t, self._pending_raw, self._pending_fixes
        self._pending_t, self._pending_raw, self._pending_fixes = np.zeros(0), np.zeros((0, 6)), []
        added, start = 0, 0
        for fix_t, pos, sigma in fixes:
            end = max(int(np.searchsorted(t, fix_t, side="right")), 1)
            if end > start:
                added += self.add_imu(t[start:end], raw[start:end, :3], raw[start:end, 3:])
                start = end
            self.add_gps(fix_t, pos, sigma)
        if start < len(t):
            added += self.add_imu(t[start:], raw[start:, :3], raw[start:, 3:])
        return added

    def _start(self) -> None:
        """Keyframe 0 at the first sample: priors on its state (an aligned start's: ``fusion.align``)."""
        pose, vel = self._first
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        priors = self.alignment.prior if self.alignment is not None else priors_on_first(pose, vel, *self._prior_sigmas)
        for prior in priors:
            graph.add(prior)
        values.insert(X(0), pose)
        values.insert(V(0), vel)
        if self._bias is not None:
            zero = gtsam.imuBias.ConstantBias()
            gyro = self._bias.gyro_prior_sigma
            if self.alignment is not None and self.alignment.still is not None and self._model is None:
                gyro = self.alignment.still.gyro_prior_sigma(gyro)  # what is left after the still start's bias
            sigmas = np.concatenate([np.full(3, self._bias.acc_prior_sigma), np.broadcast_to(gyro, (3,))])
            graph.add(gtsam.PriorFactorConstantBias(B(0), zero, gtsam.noiseModel.Diagonal.Sigmas(sigmas)))
            values.insert(B(0), zero)
        self._in_graph = 1
        self._update(graph, values)

    def _nearest_keyframe(self, t: float) -> int:
        """The decided keyframe nearest to time ``t`` (the earlier on a tie)."""
        i = min(bisect.bisect_left(self._kf_t, t), len(self._kf_t) - 1)  # kf_t[i - 1] < t <= kf_t[i]
        return i if i == 0 or self._kf_t[i] == t or t - self._kf_t[i - 1] > self._kf_t[i] - t else i - 1

    def _keyframe_for_fix(self, t: float) -> int:
        """The keyframe of a fix at ``t`` whose sample is buffered: a new one at its nearest sample when that lies
        after the last keyframe in the graph and two samples or more from the decided ones (each fix constrains the
        state at its own time), else the nearest decided keyframe. A fix that arrives after a keyframe past its time
        entered the graph is applied at the nearest keyframe, and said so once."""
        if t < self._t[0]:
            return self._late(t)
        local = int(np.clip(np.searchsorted(self._t, t), 1, len(self._t) - 1))
        local -= int(abs(self._t[local - 1] - t) <= abs(self._t[local] - t))
        j = self._base + local  # the fix's nearest sample (the buffer starts at the last keyframe in the graph)
        p = bisect.bisect_left(self._kf_index, j)
        if p < len(self._kf_index) and self._kf_index[p] == j:
            return p
        if j - self._kf_index[p - 1] < 2 or (p < len(self._kf_index) and self._kf_index[p] - j < 2):
            return self._late(t)
        self._kf_t.insert(p, float(self._t[local]))
        self._kf_index.insert(p, j)
        self._gps_for = {(k + 1 if k >= p else k): fixes for k, fixes in self._gps_for.items()}
        return p

    def _late(self, t: float) -> int:
        """The nearest decided keyframe for a fix at ``t`` that cannot have its own; a warning (once) when it lies
        more than 1.5 samples away."""
        k = self._nearest_keyframe(t)
        spacing = float(np.median(np.diff(self._t))) if len(self._t) > 1 else 0.0
        if abs(self._kf_t[k] - t) > 1.5 * spacing and not self._late_warned:
            self._late_warned = True
            log.warning(
                "OnlineFusion.add_gps: the fix at t=%.3f s arrived after the keyframe at %.3f s entered the graph and "
                "is applied there, %.3g s from its own time: add each fix before the IMU samples after it",
                t,
                self._kf_t[k],
                abs(self._kf_t[k] - t),
            )
        return k

    def _decide_keyframe(self, t: float, index: int) -> None:
        """A new keyframe at sample ``index``; waiting fixes up to ``t`` go to the nearer of it and the previous."""
        self._kf_t.append(float(t))
        self._kf_index.append(index)
        ready = [fix for fix in self._waiting if fix[0] <= t]
        self._waiting = [fix for fix in self._waiting if fix[0] > t]
        for fix in ready:
            k = len(self._kf_t) - 1
            self._attach(k - 1 if fix[0] - self._kf_t[k - 1] <= t - fix[0] else k, fix)

    def _close_keyframes(self) -> int:
        """Add every decided keyframe whose interval's samples are all corrected."""
        added = 0
        while len(self._kf_index) > self._in_graph:
            end = self._kf_index[self._in_graph] - self._base  # the interval is buffer samples [0, end)
            if len(self._samples) < end and len(self._raw) and not self._flushed:
                self._correct(flush=False)
            if len(self._samples) < end:
                break  # the model's block is not complete yet
            self._add_keyframe(end)
            added += 1
        return added

    def _correct(self, flush: bool) -> None:
        """Run the model on the raw samples not yet seen (it outputs whole blocks, and keeps the rest). Torch is
        imported here, with a model only: the estimator itself never loads it."""
        import torch

        p = next(self._model.parameters())
        gyro, acc = (torch.as_tensor(self._raw[None, :, i : i + 3], dtype=p.dtype, device=p.device) for i in (0, 3))
        with torch.no_grad():
            out, self._stream = self._model.stream(gyro, acc, self._stream, flush=flush)
        self._raw = np.zeros((0, 6))
        corrected = torch.cat([out.gyro, out.acc, out.gyro_cov, out.acc_cov], dim=-1)[0].double().cpu().numpy()
        self._samples = np.concatenate([self._samples, corrected])

    def _add_keyframe(self, end: int) -> None:
        """The learned IMU factor from the last keyframe in the graph to the next one, its fixes, one update."""
        k = self._in_graph
        s = self._samples[:end]
        samples = (s[:, 0:3], s[:, 3:6], np.diff(self._t[: end + 1]), s[:, 6:9], s[:, 9:12])
        hat = gtsam.imuBias.ConstantBias() if self._bias is None else self._bias_estimate(k - 1)
        # GTSAM's own preintegration with the learned per-sample noise: for the ~20-200 samples of one interval it
        # is much cheaper than learned_imu.preintegrate + pim_from_deltas (torch call overhead; BENCHMARKS.md)
        pim = learned_pim(*samples, self._gravity, bias=hat)
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        if self._bias is None:  # the corrected samples' bias: zero, through B(k) (module docstring)
            graph.add(gtsam.ImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(k), pim))
            graph.add(gtsam.NonlinearEqualityConstantBias(B(k), hat))
        else:  # interval k-1 -> k on the bias of keyframe k-1, and the walk to B(k)
            graph.add(gtsam.ImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(k - 1), pim))
            self._samples_seen += end
            count = self._samples_seen if self._bias.walk == "cumulative" else end
            walk = gtsam.noiseModel.Diagonal.Sigmas(self._bias.walk_sigmas(np.array([count]))[0])
            graph.add(gtsam.BetweenFactorConstantBias(B(k - 1), B(k), gtsam.imuBias.ConstantBias(), walk))
        for factor in self._gps_for.pop(k, []):
            graph.add(factor)
        predicted = pim.predict(gtsam.NavState(*self._estimate(k - 1)), hat)
        if self._motion is not None:
            body = predicted.pose().rotation().unrotate(predicted.velocity())  # R^T v, for the speed envelope
            factor = self._motion_factor(k, samples[0] - hat.gyroscope(), samples[2], np.asarray(body))
            if factor is not None:
                graph.add(factor)
        values.insert(X(k), predicted.pose())
        values.insert(V(k), predicted.velocity())
        values.insert(B(k), hat)
        self._t, self._samples, self._base = self._t[end:], self._samples[end:], self._base + end
        self._in_graph += 1
        result = self._update(graph, values)
        if self._bias is not None and not self._fixed_lag:
            copies = tuple(np.array(x) for x in samples)
            self._intervals.append(_Interval(k - 1, copies, hat, int(result.getNewFactorsIndices()[0])))
            self._relinearise()

    def _motion_factor(self, k: int, gyro: np.ndarray, dt: np.ndarray, estimate: np.ndarray) -> MotionFactor | None:
        """The motion model streamed over interval k-1 -> k (raw samples, the attitude before each one: keyframe
        k-1's estimate carried by the corrected ``gyro`` (M, 3) rad/s over ``dt`` (M,) s); the factor on keyframe k
        from its last output within one block before k's sample, None without one. ``estimate``: (3,) keyframe k's
        predicted body-frame velocity, m/s: beyond the model's speed envelope (``motion.speed_envelope``) its
        along-track axis is left to the IMU (the batch graph checks a solve with that axis free instead; a stream
        has only its prediction) and ``beyond_envelope`` counts it."""
        import torch

        rot = self._estimate(k - 1)[0].rotation()
        up = np.empty((len(dt), 3))
        for i in range(len(dt)):  # R^T e_z, before sample i
            up[i] = rot.matrix()[2]
            rot = rot.compose(gtsam.Rot3.Expmap(gyro[i] * dt[i]))
        raw, self._motion_raw = self._motion_raw[: len(dt)], self._motion_raw[len(dt) :]
        inputs = (torch.as_tensor(x[None], dtype=torch.float32) for x in (raw[:, :3], raw[:, 3:], up))
        with torch.no_grad():
            out, self._motion_stream = self._motion.stream(*inputs, self._motion_stream)
        count = out.vel.shape[1]
        if count:
            self._motion_outputs += count
            end = self._motion_outputs * self._motion.block - 1
            if end >= getattr(self._motion, "warmup_samples", 0):  # its outputs before then were never trained
                self._last_motion = (end, out.vel[0, -1].double().numpy(), out.vel_var[0, -1].double().numpy())
        if self._last_motion is None or self._last_motion[0] < self._kf_index[k] - self._motion.block:
            return None
        _, vel, var = self._last_motion
        var = var * self._motion_scale
        if self._speed_limit is not None:
            out = BodyVelocities(np.zeros(1), vel[None], var[None]).outside_envelope(estimate[None], self._speed_limit)
            var, self.beyond_envelope = out[0].var[0], self.beyond_envelope + int(out[1][0])
        return MotionFactor(X(k), V(k), vel, var)

    def _bias_estimate(self, k: int) -> gtsam.imuBias.ConstantBias:
        return self._smoother.calculateEstimateConstantBias(B(k))

    def _relinearise(self) -> int:
        """Preintegrate again, around its bias estimate, every interval whose estimate moved more than the tolerance
        from the bias its factor was preintegrated around; swap the factors in one ISAM2 update. Returns how many."""
        stale = []
        for interval in self._intervals:
            now = self._bias_estimate(interval.k)
            if np.abs(now.vector() - interval.bias_hat.vector()).max() > self._relinearise_tol:
                stale.append((interval, now))
        if not stale:
            return 0
        graph = gtsam.NonlinearFactorGraph()
        for interval, now in stale:
            pim = learned_pim(*interval.samples, self._gravity, bias=now)
            k = interval.k
            graph.add(gtsam.ImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(k), pim))
        result = self._smoother.update(graph, gtsam.Values(), [interval.index for interval, _ in stale])
        for (interval, now), index in zip(stale, result.getNewFactorsIndices(), strict=True):
            interval.bias_hat, interval.index = now, int(index)
        self.reintegrated += len(stale)
        return len(stale)

    def _converge(self) -> None:
        """At the end of the stream: ISAM2 steps and re-linearisation until no bias estimate moves more than the
        tolerance from its interval's (at most ``CONVERGE_ROUNDS``)."""
        for _ in range(CONVERGE_ROUNDS):
            self._smoother.update()
            if not self._relinearise():
                self._smoother.update()
                if not self._relinearise():
                    return
        log.warning(
            "OnlineFusion.flush: the bias estimates still moved more than relinearise_tol=%g after %d rounds",
            self._relinearise_tol,
            CONVERGE_ROUNDS,
        )

    def _attach(self, k: int, fix) -> bool:
        """The GPS factor of ``fix`` on keyframe ``k``: added now if ``k`` is in the graph, else kept for it."""
        factor = GpsFactor(X(k), fix[1], fix[2], self._lever_arm_m)
        if k >= self._in_graph:
            self._gps_for.setdefault(k, []).append(factor)
            return False
        if k in self._frozen:
            log.warning("GPS fix at t=%.3f s is older than the fixed-lag window: dropped", fix[0])
            return False
        graph = gtsam.NonlinearFactorGraph()
        graph.add(factor)
        self._update(graph, gtsam.Values())
        return True

    def _update(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values):
        if not self._fixed_lag:
            return self._smoother.update(graph, values)
        now = self._kf_t[self._in_graph - 1]
        stamps = {key: now for key in values.keys()}
        for k in range(len(self._frozen), self._in_graph):  # keyframes this update marginalises: keep their estimate
            if self._kf_t[k] >= now - self._lag_s:
                break
            self._frozen[k] = self._estimate(k)
        return self._smoother.update(graph, values, stamps)

    def _estimate(self, k: int) -> tuple[gtsam.Pose3, np.ndarray]:
        if k in self._frozen:
            return self._frozen[k]
        return self._smoother.calculateEstimatePose3(X(k)), self._smoother.calculateEstimateVector(V(k))

    def _check_samples(self, t, gyro, acc) -> tuple[np.ndarray, np.ndarray]:
        if self._flushed:
            raise InputError("add_imu: the stream was flushed; start a new OnlineFusion")
        t = np.atleast_1d(real_array(t, "add_imu: t"))
        gyro, acc = (np.atleast_2d(real_array(x, f"add_imu: {name}")) for x, name in ((gyro, "gyro"), (acc, "acc")))
        if t.ndim != 1 or gyro.shape != (len(t), 3) or acc.shape != gyro.shape:
            raise InputError(
                f"add_imu: need t (M,), gyro and acc (M, 3) (or one sample: a float and (3,)); "
                f"got {np.shape(t)}, {gyro.shape}, {acc.shape}"
            )
        raw = np.concatenate([gyro, acc], axis=1)
        if not np.all(np.isfinite(t)) or not np.all(np.isfinite(raw)):
            raise InputError(f"add_imu: NaN or Inf in the block starting at t={t[0]} s")
        before = self._pending_t[-1:] if self._first is None else self._t[-1:]
        steps = np.diff(np.concatenate([before, t]))
        if np.any(steps <= 0):
            bad = t[int(np.argmax(steps <= 0)) + 1 - len(before)]
            raise InputError(f"add_imu: timestamps must be strictly increasing; t={bad} s is not")
        models = [m for m in (self._model, self._motion) if m is not None]
        seen = self._pending_t if self._first is None else self._t
        if models and not self._rate_checked and len(seen) + len(t) >= RATE_CHECK_SAMPLES:
            self._rate_checked = True  # the models' training rate against the stream's, as correct() checks it
            from learned_imu.network.rate import check_times_rate

            for model in models:
                check_times_rate(model, np.concatenate([seen, t]), "add_imu")
        if self._model is None and self._noise_sample is not None and self._first is not None:
            self._check_noise(t, raw)  # (before an alignment the samples are checked as they are replayed)
        if self._unit_sample is not None:
            self._check_units(t, raw)
        return t, raw

    def _check_units(self, t: np.ndarray, raw: np.ndarray) -> None:
        """Once the stream spans ``UNIT_CHECK_S``: the gyro's unit from gravity and a car's turns
        (``learned_imu.datasets._tilt.check_gyro_unit``, what the readers run on a log without ground truth), a
        warning naming the likely unit and its fix: a stream cannot be re-read, so it goes on as given."""
        self._unit_sample.append((t, raw))
        if t[-1] - self._unit_sample[0][0][0] < UNIT_CHECK_S:
            return
        from learned_imu.datasets._tilt import check_gyro_unit

        seen_t = np.concatenate([block[0] for block in self._unit_sample])
        seen = np.concatenate([block[1] for block in self._unit_sample])
        self._unit_sample = None
        try:
            check_gyro_unit(seen_t, seen[:, :3], seen[:, 3:], "OnlineFusion.add_imu")
        except AirImuError as error:
            log.warning("%s (the first %g s of the stream; it goes on as given)", error, UNIT_CHECK_S)

    def _check_noise(self, t: np.ndarray, raw: np.ndarray) -> None:
        """Once ``NOISE_CHECK_SAMPLES`` raw samples are in: the given densities against the samples' own white noise
        (``factors.noise.noise_mismatch``, as ``fuse`` and ``learned_pim`` check typed constants), a warning each."""
        seen_t, seen = self._noise_sample
        seen_t, seen = np.concatenate([seen_t, t]), np.concatenate([seen, raw])
        if len(seen_t) < NOISE_CHECK_SAMPLES:
            self._noise_sample = (seen_t, seen)
            return
        self._noise_sample = None
        for sensor, columns in (("gyro", slice(0, 3)), ("acc", slice(3, 6))):
            sigma = float(np.sqrt(self._density[columns].max()))
            message = noise_mismatch(sensor, sigma, seen[:, columns], np.diff(seen_t))
            if message:
                log.warning("OnlineFusion: %s_noise_density %.3g: %s", sensor, sigma, message)


def _vector(name: str, value) -> np.ndarray:
    out = np.asarray(value, dtype=float)
    if out.shape != (3,) or not np.all(np.isfinite(out)):
        raise InputError(f"OnlineFusion: {name} must be 3 finite numbers, got {value!r}")
    return out

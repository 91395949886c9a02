"""Every window's preintegration from one pass over a chunk: deltas and 9x9 covariances from prefix quantities.

Training windows overlap (AirIMU's official EuRoC schedule starts a 1000-sample window at every 10th sample), so
integrating each on its own repeats the same products up to length / stride times. Here a chunk of N samples is
integrated once, from its first sample, and every window ``[a, b)`` inside it is read off prefix quantities
(state after n samples: rotation ``R_n``, velocity ``V_n``, position ``P_n``, time ``T_n``, chunk frame)::

    dR_ab = R_a^T R_b
    dv_ab = R_a^T (V_b - V_a)
    dp_ab = R_a^T (P_b - P_a - V_a (T_b - T_a))

which are algebraically the deltas ``preintegrate`` computes on the window's samples alone.

Covariance. Express the error state [phi, v, p] in the chunk frame. One sample's transition is
``A_k = [[I, 0, 0], [-[f_k]x h_k, I, 0], [-[f_k]x h_k^2 / 2, h_k I, I]]`` (``f_k = R_k a_k``), the same matrix
for every window containing sample k, and the product of the first n of them is
``Phi_n = [[I, 0, 0], [-[V_n]x, I, 0], [-[P_n]x, T_n I, I]]`` (block unit-triangular, so invertible in closed form).
The noise of sample j enters through ``B_j`` (gyro: ``R_{j+1} Jr(w_j h_j)``; acc: ``R_j`` into v and
``R_j h_j / 2`` into p), so the covariance of window ``[a, b)`` is::

    Sigma_ab = sum_{a <= j < b} Phi_b Phi_{j+1}^-1 B_j Q_j B_j^T Phi_{j+1}^-T Phi_b^T = Phi_b (S_b - S_a) Phi_b^T

with ``S_n`` the cumulative sum of ``Phi_{j+1}^-1 B_j Q_j B_j^T Phi_{j+1}^-T``: one cumulative sum of 9x9
matrices for the whole chunk, then one 9x9 congruence per supervised (window, end) pair. Finally the rows are
taken into the window's frame (``R_a^T`` for v and p) and the rotation into GTSAM's tangent chart at
``theta_ab = Log(dR_ab)`` (``Jr^-1(theta_ab) R_b^T``), order [rotation, position, velocity], exactly the chart of
``preintegrate``'s covariance.

Accuracy. The prefix quantities carry chunk-scale magnitudes (``|P_n|`` ~ g T^2 / 2, hundreds of metres over a
10-s chunk) while a window's deltas and covariance are window-scale, so the differences cancel digits: for the
deltas roughly chunk / window of them, for the covariance (a difference of sums, then a congruence) about
(chunk / window)^4. Everything is therefore computed in float64 by default (``dtype``), the covariance always;
the prefix of the covariance is taken from the chunk's middle state (``_recentred``), which makes that cancellation
16x smaller. Measured (``tests/learned_imu/geometry/test_windowed.py``): in float64 every window of a 20-s chunk
equals ``preintegrate`` on the window alone to 1e-9 relative (deltas ~1e-13, covariance blocks ~1e-11 for
1000-sample windows, ~1e-10 for 333-sample ones); in float32 the position deltas of 5-s windows late in a 20-s
EuRoC chunk are off by up to 1.8 mm (1.6e-5 relative), within an order of magnitude of the errors the loss sees
(centimetres over 5 s), which is why float32 is not the default.
"""

from __future__ import annotations

import torch

from airimu_core.errors import InputError
from learned_imu.geometry import so3
from learned_imu.geometry.preintegration import (
    Preintegrated,
    _check_density,
    _check_samples,
    _integrate,
    _mm,
    _samples_first,
    _samples_last,
    _tr,
)

COVARIANCE_DTYPE = torch.float64  # see the module docstring: the prefix-difference covariance needs it


def window_ends(starts: torch.Tensor, length: int, every: int) -> torch.Tensor:
    """(M, K) prefix indices of the supervised states: ``a + every, a + 2 every, ..., <= a + length`` for each
    start a (the states after the samples ``preintegrate(..., at=slice(every - 1, None, every))`` reports)."""
    k = torch.arange(1, length // every + 1, device=starts.device)
    return starts[:, None] + every * k


def preintegrate_windows(
    gyro: torch.Tensor,
    acc: torch.Tensor,
    dt: torch.Tensor,
    starts,
    length: int,
    every: int,
    gyro_cov=None,
    acc_cov=None,
    rotation: torch.Tensor | None = None,
    dtype: torch.dtype | None = torch.float64,
    diagonal: bool = False,
) -> Preintegrated:
    """Preintegrate every window ``[a, a + length)`` of a chunk, ``a`` in ``starts``, from one pass (module docstring).

    Equal to ``preintegrate(gyro[..., a:a + length, :], acc[...], dt[...], gyro_cov[...], acc_cov[...],
    at=slice(every - 1, None, every))`` for each start, to 1e-9 relative in float64 (module docstring).

    Args:
        gyro, acc: (..., N, 3) chunk samples, rad/s and m/s^2, IMU frame.
        dt: (..., N) time step of each sample (forward, ``t[i+1] - t[i]``), s; or a float.
        starts: (M,) window starts, sample indices into N (the same for every chunk of the batch).
        length: window length, samples; every start must satisfy ``a + length <= N``.
        every: supervise the state after every ``every``-th sample of each window (K = length // every states).
        gyro_cov, acc_cov: noise densities as ``preintegrate`` takes them (rad^2/s, m^2/s^3: a float, (3,) or
            (..., N, 3)); both or neither.
        rotation: (..., N, 3, 3) or None: a known rotation of the IMU frame at each sample (any fixed world frame,
            e.g. the ground truth's), with which velocity and position are integrated instead of the gyro's
            (the official AirIMU's ``gtrot``): their deltas ``R_a^T sum R_k a_k h_k`` then carry no rotation error,
            their covariance only the accelerometer's noise, and only ``rot`` depends on the gyro.
        dtype: the dtype the deltas are computed and returned in (None: the samples'); float64 by default (module
            docstring, "Accuracy"); the covariance is always float64.
        diagonal: return only the covariance's diagonal, as ``variance`` (``cov`` None): what a diagonal likelihood
            needs, without the off-diagonal blocks' products.

    Returns:
        ``Preintegrated`` with fields (..., M, K, ...): ``rot``, ``vel``, ``pos``, ``dt`` (elapsed time since the
        window's start) in ``dtype``, ``cov`` (..., M, K, 9, 9) float64 when densities are given, in
        GTSAM's tangent order [rotation, position, velocity] (with ``diagonal``, ``variance`` (..., M, K, 9)).
    """
    gyro, acc, dt = _check_samples(gyro, acc, dt)
    if dtype is not None:
        gyro, acc, dt = gyro.to(dtype), acc.to(dtype), dt.to(dtype)
    starts = _check_starts(starts, length, every, gyro.shape[-2]).to(gyro.device)
    if (gyro_cov is None) != (acc_cov is None):
        raise InputError("preintegrate_windows: give both gyro_cov and acc_cov, or neither")
    known = None if rotation is None else _check_rotation(rotation, gyro)
    h, step_jacobian, rot, rot_before, _, vel, pos = _integrate(gyro, acc, dt, known)
    elapsed = torch.cumsum(h, dim=-1)  # (..., 1, N)
    # prefix arrays, samples last: index n is the state after n samples (n = 0: identity, zeros)
    prefix = _Prefix(
        torch.cat([rot_before, rot[..., -1:]], dim=-1), _zero_first(vel), _zero_first(pos), _zero_first(elapsed)
    )
    frame = rot_before if known is None else known  # the rotation velocity and position are integrated with
    ends = window_ends(starts, length, every)
    shape = ends.shape  # (M, K)
    a = starts[:, None].expand(shape).reshape(-1)  # pairs (window start, supervised end), flattened
    b = ends.reshape(-1)
    r_a, r_b = prefix.rot[..., a], prefix.rot[..., b]
    v_a, t_a, t_b = prefix.vel[..., a], prefix.time[..., a], prefix.time[..., b]
    span = t_b - t_a  # (..., 1, P)
    rot_ab = _mm(_tr(r_a), r_b)
    f_a = r_a if known is None else frame[..., a]
    back = _tr(f_a)  # R_a^T
    vel_ab = so3.matvec(back, prefix.vel[..., b] - v_a, dim=-2)
    pos_ab = so3.matvec(back, prefix.pos[..., b] - prefix.pos[..., a] - v_a * span, dim=-2)
    cov = None
    if gyro_cov is not None:
        d = COVARIANCE_DTYPE
        gyro_cov = _samples_last(_check_density("gyro_cov", gyro_cov, gyro)).to(d)
        acc_cov = _samples_last(_check_density("acc_cov", acc_cov, acc)).to(d)
        wide = _recentred(_Prefix(*(x.to(d) for x in prefix)))
        lever = _mm(rot.to(d), step_jacobian.to(d))  # R_{j+1} Jr(w_j h_j)
        coupled = known is None
        noise = _noise_terms(lever, frame.to(d), h.to(d), wide, gyro_cov, acc_cov, coupled)
        window = _window_sums(noise, a, b)  # (..., 6, 3, 3, P): S_b - S_a
        cov = _window_covariance(
            window,
            rot_ab.to(d),
            f_a.to(d),
            r_b.to(d),
            wide.vel[..., b],
            wide.pos[..., b],
            wide.time[..., b],
            coupled,
            diagonal,
        )

    def out(x: torch.Tensor, item_ndim: int) -> torch.Tensor:
        return _samples_first(x, item_ndim).unflatten(-1 - item_ndim, shape)

    return Preintegrated(
        rot=out(rot_ab, 2),
        vel=out(vel_ab, 1),
        pos=out(pos_ab, 1),
        dt=span[..., 0, :].unflatten(-1, shape),
        cov=None if cov is None or diagonal else out(cov, 2),
        variance=out(cov, 1) if cov is not None and diagonal else None,
    )


class _Prefix(tuple):
    """Samples-last prefix states (index n: after n samples): rot (..., 3, 3, N+1), vel, pos (..., 3, N+1),
    time (..., 1, N+1), chunk frame."""

    def __new__(cls, rot, vel, pos, time):
        return super().__new__(cls, (rot, vel, pos, time))

    rot = property(lambda self: self[0])
    vel = property(lambda self: self[1])
    pos = property(lambda self: self[2])
    time = property(lambda self: self[3])


def _recentred(prefix: _Prefix) -> _Prefix:
    """The prefix as if integrated from the chunk's middle state r (``V_n - V_r``, ``P_n - P_r - (T_n - T_r) V_r``,
    ``T_n - T_r``): ``Phi_b Phi_{j+1}^-1 = Phi(b, r) Phi(j+1, r)^-1``, and ``Phi(n, r)`` is ``Phi_n`` of these, so the
    covariance is the same while the magnitudes that cancel are halved (16x less round-off, module docstring)."""
    r = prefix.time.shape[-1] // 2
    v_r, t = prefix.vel[..., r : r + 1], prefix.time - prefix.time[..., r : r + 1]
    return _Prefix(prefix.rot, prefix.vel - v_r, prefix.pos - prefix.pos[..., r : r + 1] - t * v_r, t)


def _noise_terms(lever, rot_before, h, prefix: _Prefix, gyro_cov, acc_cov, coupled: bool = True) -> torch.Tensor:
    """(..., 6, 3, 3, N) the blocks (phi phi, v phi, v v, p phi, p v, p p) of the terms
    ``Phi_{j+1}^-1 B_j Q_j B_j^T Phi_{j+1}^-T`` whose cumulative sum is ``S_n`` (module docstring), chunk frame.
    ``coupled=False``: velocity and position integrated with a known rotation, so the rotation error does not enter
    them (``Phi`` has no ``[V]x``, ``[P]x`` blocks); ``rot_before`` is then that rotation."""
    hh = h[..., None, :, :]
    v_next, p_next, t_next = prefix.vel[..., 1:], prefix.pos[..., 1:], prefix.time[..., None, :, 1:]
    g = _mm(lever * (gyro_cov * h)[..., None, :, :], lever, True)  # gyro noise of the phi increment
    q = _mm(rot_before * (acc_cov * h)[..., None, :, :], rot_before, True)  # acc noise of the v increment
    # Phi_{j+1}^-1 = [[I, 0, 0], [K_v, I, 0], [K_p, -T I, I]], K_v = [V]x, K_p = [P]x - T [V]x; acc noise
    # enters p as (h / 2 - T) times its v increment
    c = 0.5 * hh - t_next
    if coupled:
        k_v = so3.hat(v_next, dim=-2)
        k_p = so3.hat(p_next, dim=-2) - t_next * k_v
        k_v_g, k_p_g = _mm(k_v, g), _mm(k_p, g)
        v_v, p_v, p_p = _mm(k_v_g, k_v, True) + q, _mm(k_p_g, k_v, True) + c * q, _mm(k_p_g, k_p, True) + c * c * q
    else:
        k_v_g = k_p_g = torch.zeros_like(g)
        v_v, p_v, p_p = q, c * q, c * c * q
    increments = torch.stack((g, k_v_g, v_v, k_p_g, p_v, p_p), dim=-4)
    return increments


def _window_covariance(
    window, rot_ab, r_a, r_b, v_b, p_b, t_b, coupled: bool = True, diagonal: bool = False
) -> torch.Tensor:
    """(..., 9, 9, P) covariance of each window in its own frame and GTSAM's tangent chart, order [rotation,
    position, velocity], from ``S_b - S_a`` (``window``, chunk frame): ``C Phi_b (S_b - S_a) Phi_b^T C^T``, block by
    block (module docstring). ``r_a``: the rotation velocity and position were integrated with, at the window's
    start; ``coupled`` as in ``_noise_terms``. ``diagonal``: only the diagonal, (..., 9, P)."""
    d_rr, d_vr, d_vv, d_pr, d_pv, d_pp = window.unbind(-4)
    t = t_b[..., None, :, :]
    if coupled:
        x, y = -so3.hat(v_b, dim=-2), -so3.hat(p_b, dim=-2)  # Phi_b's blocks
        s_vr = _mm(x, d_rr) + d_vr
        s_pr = _mm(y, d_rr) + t * d_vr + d_pr
        w_v = _mm(y, d_vr, True) + t * d_vv + d_pv
        s_vv = _mm(s_vr, x, True) + _mm(x, d_vr, True) + d_vv
        s_pv = None if diagonal else _mm(s_pr, x, True) + w_v
        s_pp = _mm(s_pr, y, True) + t * w_v + _mm(y, d_pr, True) + t * _tr(d_pv) + d_pp
    else:  # Phi_b = [[I, 0, 0], [0, I, 0], [0, T I, I]]
        s_vr, s_pr, s_vv = d_vr, t * d_vr + d_pr, d_vv
        w_v = t * d_vv + d_pv
        s_pv = w_v
        s_pp = t * w_v + t * _tr(d_pv) + d_pp
    to_tangent = _mm(so3.log_and_right_jacobian_inv(rot_ab, dim=-2)[1], r_b, True)  # Jr^-1(theta_ab) R_b^T
    back = _tr(r_a)

    def congruent(left, block, right):  # left block right^T
        return _mm(_mm(left, block), right, True)

    if diagonal:  # diag(L S L^T)_i = sum_k (L S)_ik L_ik
        blocks = ((to_tangent, d_rr), (back, s_pp), (back, s_vv))
        return torch.cat([(_mm(left, block) * left).sum(dim=-2) for left, block in blocks], dim=-2)
    c_rr = congruent(to_tangent, d_rr, to_tangent)
    c_pr, c_vr = congruent(back, s_pr, to_tangent), congruent(back, s_vr, to_tangent)
    c_pp, c_pv, c_vv = (congruent(back, block, back) for block in (s_pp, s_pv, s_vv))
    rows = ((c_rr, _tr(c_pr), _tr(c_vr)), (c_pr, c_pp, c_pv), (c_vr, _tr(c_pv), c_vv))
    return torch.cat([torch.cat(row, dim=-2) for row in rows], dim=-3)


def _check_rotation(rotation, gyro: torch.Tensor) -> torch.Tensor:
    """(..., N, 3, 3) rotations like the samples -> samples last (..., 3, 3, N)."""
    if not isinstance(rotation, torch.Tensor) or rotation.shape != gyro.shape + (3,):
        got = tuple(rotation.shape) if isinstance(rotation, torch.Tensor) else type(rotation).__name__
        want = tuple(gyro.shape) + (3,)
        raise InputError(f"preintegrate_windows: rotation must be a tensor shaped {want}; got {got}")
    if not torch.isfinite(rotation).all():
        raise InputError("preintegrate_windows: rotation contains NaN or Inf")
    return rotation.to(gyro.dtype).movedim(-3, -1).contiguous()


def _window_sums(terms: torch.Tensor, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(..., P) sums ``sum_{a_p <= j < b_p} terms[..., j]`` of per-sample terms (..., N): the difference of two
    entries of their cumulative sum, with a backward that is one cumulative sum of a difference array instead of
    autograd's gather, subtraction and reversed cumulative sum (each the size of the terms)."""
    return _WindowSums.apply(terms, a, b)


class _WindowSums(torch.autograd.Function):
    @staticmethod
    def forward(ctx, terms, a, b):
        prefix = _zero_first(torch.cumsum(terms, dim=-1))
        ctx.save_for_backward(a, b)
        ctx.samples = terms.shape[-1]
        return prefix.index_select(-1, b) - prefix.index_select(-1, a)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad):
        a, b = ctx.saved_tensors
        edges = grad.new_zeros(*grad.shape[:-1], ctx.samples + 1)
        edges.index_add_(-1, a, grad)
        edges.index_add_(-1, b, -grad)
        return torch.cumsum(edges, dim=-1)[..., : ctx.samples], None, None


def _zero_first(x: torch.Tensor) -> torch.Tensor:
    """A zero in front along the (last) samples axis."""
    return torch.cat([torch.zeros_like(x[..., :1]), x], dim=-1)


def _check_starts(starts, length: int, every: int, n: int) -> torch.Tensor:
    if not (isinstance(length, int) and isinstance(every, int) and 1 <= every <= length):
        raise InputError(
            f"preintegrate_windows: need whole numbers 1 <= every <= length; got every {every}, length {length}"
        )
    starts = torch.as_tensor(starts)
    if starts.ndim != 1 or starts.numel() == 0 or starts.dtype.is_floating_point or starts.dtype == torch.bool:
        raise InputError("preintegrate_windows: starts must be a non-empty 1-D sequence of sample indices")
    starts = starts.long()
    if int(starts.min()) < 0 or int(starts.max()) + length > n:
        raise InputError(
            f"preintegrate_windows: windows of {length} samples starting at {int(starts.min())}..{int(starts.max())} "
            f"do not fit in a chunk of {n} samples"
        )
    return starts

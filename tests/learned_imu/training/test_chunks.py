"""Training chunks (``learned_imu.training.chunks``) on real EuRoC flights and KITTI drives against the per-window path
(``make_windows``): the same window starts, each once; the same errors and variances in float64 (the ground-truth
start of every window); windows across a real time gap left out; ``chunk_offsets`` over many small cases; the
``Chunks`` operations and refusals; the masked loss; and a short training run on chunks."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest
import torch

from airimu_core.errors import InputError
from airimu_core.sequence import gap_indices
from learned_imu.datasets import read_sequence
from learned_imu.network.model import AirImuNet, Correction
from learned_imu.training.chunks import Chunks, chunk_offsets, concat_chunks, make_chunks
from learned_imu.training.losses import LossWeights, total_loss
from learned_imu.training.train import Trainer
from learned_imu.training.windows import make_windows

F64 = torch.float64
BLOCKS = {"rotation": slice(0, 3), "position": slice(3, 6), "velocity": slice(6, 9)}
KITTI_REPAIR = {"on_backward": "drop", "on_duplicate": "drop", "on_gap": "keep"}  # gaps kept, not split


@pytest.fixture(scope="module")
def mh01(shared_data):
    return read_sequence("euroc", shared_data / "euroc/MH_01_easy")


def sample_index(seq, dtype=torch.float32) -> dict[bytes, int]:
    """Sample i of ``seq`` by its IMU rows i and i + 1 in ``dtype`` (unique on real data: asserted)."""
    rows = torch.as_tensor(np.concatenate([seq.gyro, seq.acc], axis=1), dtype=dtype).numpy()
    pairs = np.ascontiguousarray(np.concatenate([rows[:-1], rows[1:]], axis=1))
    index = {pair.tobytes(): i for i, pair in enumerate(pairs)}
    assert len(index) == len(pairs), "two samples with the same IMU rows: the lookup would be ambiguous"
    return index


def located(index: dict[bytes, int], gyro: torch.Tensor, acc: torch.Tensor, at: int) -> np.ndarray:
    """(B,) the sequence sample at row ``at`` of each of B stretches of network input (``index`` of their dtype)."""
    rows = torch.cat([gyro, acc], dim=-1).numpy()
    pairs = np.ascontiguousarray(np.concatenate([rows[:, at], rows[:, at + 1]], axis=1))
    return np.array([index[pair.tobytes()] for pair in pairs])


def chunk_origins(chunks: Chunks, seq, index) -> np.ndarray:
    """(B,) the sequence sample each chunk's first integrated sample is, recovered from its samples, whose every row
    (context included) and time step are checked against the sequence."""
    offsets = located(index, chunks.gyro, chunks.acc, chunks.context)
    n = chunks.dt.shape[1]
    for b, offset in enumerate(offsets):
        fed = slice(offset - chunks.context, offset + n)
        assert torch.equal(chunks.gyro[b], torch.as_tensor(seq.gyro[fed], dtype=chunks.gyro.dtype)), b
        assert torch.equal(chunks.acc[b], torch.as_tensor(seq.acc[fed], dtype=chunks.acc.dtype)), b
        np.testing.assert_allclose(chunks.dt[b].double().numpy(), seq.dt[offset : offset + n], rtol=1e-6)
    return offsets


def window_starts(windows, index) -> np.ndarray:
    """(W,) the sequence sample each window of ``make_windows`` starts at (its first integrated sample)."""
    return located(index, windows.gyro, windows.acc, windows.context)


def held_starts(chunks: Chunks, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Global starts of the chunks' valid windows, and their (chunk, window) indices."""
    b, m = np.nonzero(chunks.valid.numpy())
    return offsets[b] + chunks.starts.numpy()[m], b, m


def both_paths(seq, chunk: int, length: int, every: int, stride: int, context: int):
    """float64 chunks and windows of ``seq``, the chunks' offsets in it, and their valid (start, chunk, slot)."""
    chunks = make_chunks(seq, chunk, length, every, stride, dtype=F64, context=context)
    windows = make_windows(seq, length, every, stride, dtype=F64, context=context)
    offsets = chunk_origins(chunks, seq, sample_index(seq, F64))
    return chunks, windows, offsets, held_starts(chunks, offsets)


def relative(x: torch.Tensor, y: torch.Tensor) -> float:
    return float((x - y).abs().max() / y.abs().max())


@pytest.mark.parametrize("chunk", [3000, 2995])
def test_chunks_hold_exactly_the_windows_make_windows_cuts(mh01, chunk):
    """MH_01 with the official schedule (1000 samples, every 50th supervised, a window every 10th sample) and 18
    samples of context: every window make_windows cuts is a valid window of exactly one chunk, and no other is;
    2995 is rounded down to 2990 (length + 199 strides)."""
    length, every, stride, context = 1000, 50, 10, 18
    chunks = make_chunks(mh01, chunk, length, every, stride, context=context)
    windows = make_windows(mh01, length, every, stride, context=context)
    index = sample_index(mh01)
    m = (chunk - length) // stride + 1
    assert chunks.dt.shape[1] == length + (m - 1) * stride and chunks.gyro.shape[1] == context + chunks.dt.shape[1]
    assert torch.equal(chunks.starts, torch.arange(m) * stride) and chunks.valid.shape == (len(chunks), m)
    assert chunks.truth.rot.shape == (len(chunks), m, length // every, 3, 3)
    offsets = chunk_origins(chunks, mh01, index)
    got, _, _ = held_starts(chunks, offsets)
    want = window_starts(windows, index)
    assert len(np.unique(got)) == len(got), "a window held by two chunks"
    np.testing.assert_array_equal(np.sort(got), np.sort(want))
    assert chunks.windows == len(windows)
    # the ground truth is valid throughout and has no gap: that is the whole grid of starts whose window fits
    grid = np.arange(context, len(mh01) - length, stride)
    np.testing.assert_array_equal(np.sort(got), grid)
    # the last chunk was moved back to end on the last usable sample: it shares windows with the one before it
    assert offsets[-1] + chunks.dt.shape[1] <= len(mh01) - 1 and offsets[-1] - offsets[-2] < m * stride
    assert not chunks.valid[-1, 0] and chunks.valid[-1, -1]


def test_windows_touching_invalid_ground_truth_are_left_out_as_make_windows_leaves_them(shared_data):
    """MH_01 read without cropping to the ground truth: its first 216 and last 222 IMU samples have none; windows
    whose context or samples touch them are not valid in any chunk, exactly as make_windows drops them."""
    seq = read_sequence("euroc", shared_data / "euroc/MH_01_easy", crop_to_gt=False)
    length, every, stride, context = 1000, 50, 10, 18
    invalid = np.flatnonzero(~seq.gt.valid)
    assert len(invalid) > 400 and invalid[0] == 0 and invalid[-1] == len(seq) - 1
    chunks = make_chunks(seq, 3000, length, every, stride, context=context)
    windows = make_windows(seq, length, every, stride, context=context)
    index = sample_index(seq)
    got, _, _ = held_starts(chunks, chunk_origins(chunks, seq, index))
    want = window_starts(windows, index)
    np.testing.assert_array_equal(np.sort(got), np.sort(want))
    assert len(np.unique(got)) == len(got)
    grid = np.arange(context, len(seq) - length, stride)
    states_valid = np.array([seq.gt.valid[s - context : s + length + 1].all() for s in grid])
    np.testing.assert_array_equal(np.sort(got), grid[states_valid])
    assert (~states_valid).sum() > 40  # some windows really were left out, at both ends
    assert got.min() > invalid[invalid < len(seq) // 2].max() + context
    assert got.max() + length < invalid[invalid > len(seq) // 2].min()


@pytest.fixture(scope="module")
def flight_errors(mh01):
    """Errors and variances (the covariance's diagonal) of every window of 12 s of MH_01 in flight, from chunks
    (float64, 3000 samples: one chunk and one moved back over two thirds of it) and from make_windows, for the same
    per-sample corrections and densities (those of the chunk that owns each window)."""
    seq = mh01.part(0.3, 0.42)
    length, every, stride, context = 1000, 50, 10, 18
    chunks, windows, _, (starts, b, m) = both_paths(seq, 3000, length, every, stride, context)
    index = sample_index(seq, F64)
    order = {int(s): i for i, s in enumerate(window_starts(windows, index))}
    pick = np.array([order[int(s)] for s in starts])  # the make_windows window of each valid (b, m)
    g = torch.Generator().manual_seed(0)
    size = chunks.dt.shape
    raw_gyro, raw_acc = chunks.gyro[:, context:], chunks.acc[:, context:]
    d_gyro = 1e-3 * torch.randn(*size, 3, generator=g, dtype=F64)
    d_acc = 1e-2 * torch.randn(*size, 3, generator=g, dtype=F64)
    slow = 1 + 0.5 * torch.sin(torch.arange(size[1], dtype=F64) / 150)[None, :, None]  # densities varying in time
    gyro_cov = 2.9e-8 * slow * (1 + torch.rand(*size, 3, generator=g, dtype=F64))
    acc_cov = 4e-6 * slow * (1 + torch.rand(*size, 3, generator=g, dtype=F64))
    out = Correction(raw_gyro + d_gyro, raw_acc + d_acc, d_gyro, d_acc, gyro_cov, acc_cov)
    chunk_errors, chunk_var = chunks.errors(out, out.gyro_cov, out.acc_cov)  # variances: the covariance's diagonal
    local = chunks.starts.numpy()[m]
    take = torch.as_tensor(local[:, None] + np.arange(length))  # (W, L) samples of each window in its chunk
    rows = torch.as_tensor(b)[:, None]

    def cut(x):
        return x[rows, take]

    per_window = Correction(*(cut(getattr(out, f.name)) for f in dataclasses.fields(Correction)))
    selected = windows.select(torch.as_tensor(pick))
    assert torch.equal(selected.gyro[:, context:], cut(raw_gyro)) and torch.equal(selected.dt, cut(chunks.dt))
    window_errors, window_var = selected.errors(per_window, per_window.gyro_cov, per_window.acc_cov)
    return chunks, chunk_errors, chunk_var, (b, m), window_errors, window_var, len(windows)


def test_chunk_errors_and_variances_equal_the_per_window_path(flight_errors):
    """Every window's errors and variances from the chunk's one pass equal make_windows' per-window preintegration
    against its own ground-truth start and targets: the chunks' precomputed truth deltas start where they should."""
    chunks, chunk_errors, chunk_var, (b, m), window_errors, window_var, count = flight_errors
    assert len(chunks) == 2 and len(b) == count == chunks.windows  # every make_windows window compared
    assert chunk_errors.shape == chunk_var.shape == (*chunks.valid.shape, 20, 9) and chunk_var.dtype == F64
    ours, theirs = chunk_errors[b, m], window_errors
    assert relative(ours, theirs) < 1e-9
    for name, part in BLOCKS.items():  # each block on its own scale (rotation's is ~1e-6 of position's)
        assert relative(ours[..., part], theirs[..., part]) < 1e-9, name
        assert relative(chunk_var[b, m][..., part], window_var[..., part]) < 1e-9, name
    # a window's truth taken one stride late would be far off: the comparison can tell
    shifted = window_errors[1:]
    same_chunk = (b[1:] == b[:-1]) & (m[1:] == m[:-1] + 1)
    assert relative(ours[:-1][same_chunk][..., 3:6], shifted[same_chunk][..., 3:6]) > 1e-3


@pytest.mark.parametrize("drive, gaps", [("2011_09_26_drive_0009", 1), ("2011_09_26_drive_0014", 2)])
def test_windows_across_a_real_kitti_gap_are_masked_out(shared_data, drive, gaps):
    """KITTI raw drives read with their gaps kept (0009: 0.55 s without OXTS packets; 0014: two of 70 ms): no valid
    window of any chunk, context included, bridges a gap, the windows left are make_windows', and their errors are
    the per-window ones although the chunk was integrated across the gap."""
    seq = read_sequence("kitti_raw", shared_data / "kitti_raw" / f"{drive}.csv", **KITTI_REPAIR)
    gap = gap_indices(seq.t)  # sample gap[i] is followed by a gap
    assert len(gap) == gaps and np.diff(seq.t)[gap].min() > 0.06
    length, every, stride, context = 200, 10, 20, 10
    chunks, windows, offsets, (starts, b, m) = both_paths(seq, 1000, length, every, stride, context)
    index = sample_index(seq, F64)
    window_at = window_starts(windows, index)
    np.testing.assert_array_equal(np.sort(starts), np.sort(window_at))
    assert len(np.unique(starts)) == len(starts)
    spans = (starts[:, None] - context <= gap) & (gap <= starts[:, None] + length - 1)  # (W, gaps)
    assert not spans.any()
    grid = np.arange(context, len(seq) - length, stride)
    crossing = ((grid[:, None] - context <= gap) & (gap <= grid[:, None] + length - 1)).any(axis=1)
    np.testing.assert_array_equal(np.sort(starts), grid[~crossing])  # only those left out, and all of them
    assert crossing.sum() >= gaps * (length // stride)
    # some chunk holds a gap, with valid windows on both sides of it
    local = gap[:, None] - offsets
    holding = (local >= 0) & (local < chunks.dt.shape[1])
    gi, ci = np.nonzero(holding)
    assert any(
        ((b == c) & (starts < gap[g])).any() and ((b == c) & (starts > gap[g])).any()
        for g, c in zip(gi, ci, strict=True)
    )

    # and the errors of every valid window equal the per-window ones
    def raw(data, samples: int) -> Correction:  # the samples uncorrected, constant densities
        shape = (len(data), samples, 3)
        density = torch.full(shape, 1e-5, dtype=F64), torch.full(shape, 1e-3, dtype=F64)
        return Correction(data.gyro[:, context:], data.acc[:, context:], None, None, *density)

    out = raw(chunks, chunks.dt.shape[1])
    errors, variance = chunks.errors(out, out.gyro_cov, out.acc_cov)
    order = {int(s): i for i, s in enumerate(window_at)}
    selected = windows.select(torch.as_tensor([order[int(s)] for s in starts]))
    plain = raw(selected, length)
    want, want_var = selected.errors(plain, plain.gyro_cov, plain.acc_cov)
    for name, part in BLOCKS.items():
        assert relative(errors[b, m][..., part], want[..., part]) < 1e-9, name
        assert relative(variance[b, m][..., part], want_var[..., part]) < 1e-9, name


def test_chunk_offsets_own_every_grid_start_exactly_once():
    """Over 23,552 small (n, chunk, length, stride, context): every chunk fits, on the grid, and every window start
    make_windows would cut (``context + k stride``, ``s + length <= n - 1``) is owned by exactly one chunk, no other
    start by any; where no chunk fits there is none."""
    cases = 0
    for n, length, stride, context, extra in itertools.product(
        range(2, 48), range(1, 9), range(1, 5), range(4), range(4)
    ):
        chunk = length + extra * stride
        offsets, owned = chunk_offsets(n, chunk, length, stride, context)
        assert offsets.shape == owned.shape
        if n - 1 - chunk < context:  # no chunk fits
            assert len(offsets) == 0
            continue
        cases += 1
        m = extra + 1
        assert len(offsets) >= 1 and (offsets >= context).all() and ((offsets - context) % stride == 0).all()
        assert (offsets + chunk <= n - 1).all()
        last_held = offsets + (m - 1) * stride
        assert ((owned - offsets) % stride == 0).all() and (owned >= offsets).all() and (owned <= last_held).all()
        grid = np.arange(context, n - length, stride)  # make_windows' starts: s + length <= n - 1
        owners = ((grid[:, None] >= owned) & (grid[:, None] <= last_held)).sum(axis=1)
        assert (owners == 1).all(), (n, chunk, length, stride, context)
        held = np.concatenate([np.arange(a, z + 1, stride) for a, z in zip(owned, last_held, strict=True)])
        assert np.isin(held, grid).all() and len(held) == len(grid), (n, chunk, length, stride, context)
    assert cases > 10000


@pytest.fixture(scope="module")
def short_chunks(mh01):
    """Chunks of 15 s of MH_01 with every optional field (gravity in the IMU frame, ground-truth rotations)."""
    seq = mh01.part(0.3, 0.38)
    chunks = make_chunks(seq, 1500, 500, 50, 50, context=18, remove_gravity=True, gt_rotation=True)
    return seq, chunks


def tensors(c: Chunks) -> dict[str, torch.Tensor]:
    return {
        "gyro": c.gyro,
        "acc": c.acc,
        "dt": c.dt,
        "valid": c.valid,
        "gravity_imu": c.gravity_imu,
        "rotation": c.rotation,
        **{f"truth.{f}": getattr(c.truth, f) for f in ("rot", "vel", "pos", "dt")},
    }


def test_select_to_double_and_concat_keep_shapes_and_masks(short_chunks):
    _, chunks = short_chunks
    assert len(chunks) >= 3 and chunks.gravity_imu.shape == chunks.gyro.shape
    index = torch.tensor([2, 0])
    picked = chunks.select(index)
    assert len(picked) == 2 and torch.equal(picked.mask, chunks.valid[index])
    assert torch.equal(picked.starts, chunks.starts)
    assert picked.windows == int(chunks.valid[index].sum())
    for name, x in tensors(picked).items():
        assert torch.equal(x, tensors(chunks)[name][index]), name
    assert (picked.length, picked.every, picked.context) == (chunks.length, chunks.every, chunks.context)
    moved = chunks.to("cpu")
    for name, x in tensors(moved).items():
        assert torch.equal(x, tensors(chunks)[name]), name
    double = chunks.double()
    assert double.valid.dtype == torch.bool and double.starts.dtype == torch.long
    assert torch.equal(double.mask, chunks.mask)
    for name, x in tensors(double).items():
        if name != "valid":
            assert x.dtype == F64 and torch.equal(x, tensors(chunks)[name].double()), name
    both = concat_chunks([chunks, picked])
    assert len(both) == len(chunks) + 2 and both.windows == chunks.windows + picked.windows
    assert torch.equal(both.mask, torch.cat([chunks.valid, picked.valid])) and torch.equal(both.starts, chunks.starts)
    for name, x in tensors(both).items():
        assert torch.equal(x, torch.cat([tensors(chunks)[name], tensors(picked)[name]])), name
    assert concat_chunks([chunks]) is chunks


def test_concat_refuses_chunks_of_other_lengths_or_windows(short_chunks):
    seq, chunks = short_chunks
    others = {
        "chunk": make_chunks(seq, 1000, 500, 50, 50, context=18),
        "length": make_chunks(seq, 1500, 450, 50, 50, context=18),  # the same samples, other windows
        "every": make_chunks(seq, 1500, 500, 25, 50, context=18),
        "stride": make_chunks(seq, 1500, 500, 50, 100, context=18),
        "context": make_chunks(seq, 1500, 500, 50, 50, context=9),
    }
    assert others["length"].dt.shape == chunks.dt.shape
    for other in others.values():
        with pytest.raises(InputError, match="concat_chunks: chunks differ"):
            concat_chunks([chunks, other])
    with pytest.raises(InputError, match="no chunks given"):
        concat_chunks([])


def test_concat_refuses_chunks_made_with_and_without_the_optional_inputs(short_chunks):
    seq, chunks = short_chunks
    plain = make_chunks(seq, 1500, 500, 50, 50, context=18)
    for parts in ([chunks, plain], [plain, chunks]):
        with pytest.raises(InputError, match="made with remove_gravity and some without"):
            concat_chunks(parts)
    rotation_only = make_chunks(seq, 1500, 500, 50, 50, context=18, gt_rotation=True)
    with pytest.raises(InputError, match="made with gt_rotation and some without"):
        concat_chunks([plain, rotation_only])


def test_invalid_ground_truth_rotations_do_not_poison_the_network_input(short_chunks):
    """NaN rotations where the ground truth is invalid: the windows there are left out, and the gravity fed to the
    network and the rotations used for integration stay finite, so the chunk's other windows still train."""
    seq, _ = short_chunks
    rot, valid = seq.gt.rot.copy(), seq.gt.valid.copy()
    rot[700:710], valid[700:710] = np.nan, False
    broken = dataclasses.replace(seq, gt=dataclasses.replace(seq.gt, rot=rot, valid=valid))
    chunks = make_chunks(broken, 1500, 500, 50, 50, context=18, remove_gravity=True, gt_rotation=True)
    assert torch.isfinite(chunks.gravity_imu).all() and torch.isfinite(chunks.rotation).all()
    assert 0 < chunks.windows < make_chunks(seq, 1500, 500, 50, 50, context=18).windows
    model = AirImuNet(gru_sizes=(16, 16)).eval()
    out = chunks.correct(model)
    errors, variance = chunks.errors(out, out.gyro_cov, out.acc_cov)
    assert torch.isfinite(errors[chunks.mask]).all() and torch.isfinite(variance[chunks.mask]).all()


def test_chunk_offsets_refuse_a_chunk_off_the_stride_grid():
    with pytest.raises(InputError, match="multiple of stride"):
        chunk_offsets(4, 2, 1, 2, 0)


def test_refusals_and_empty_results_are_clear(mh01, shared_data):
    seq = mh01.part(0.3, 0.38)
    with pytest.raises(InputError, match="a chunk of 400 samples cannot hold a window of 500"):
        make_chunks(seq, 400, 500, 50, 50)
    with pytest.raises(InputError, match="training chunks need ground truth"):
        make_chunks(dataclasses.replace(seq, gt=None), 1500, 500, 50, 50)
    for every, stride, context in ((0, 50, 0), (600, 50, 0), (50, 0, 0), (50, 50, -1)):
        with pytest.raises(InputError, match="need 1 <= every <= length, stride >= 1 and context >= 0"):
            make_chunks(seq, 1500, 500, every, stride, context=context)
    # the first 216 samples of MH_01 have no ground truth (read uncropped): chunks fit, no window in them is usable
    head = read_sequence("euroc", shared_data / "euroc/MH_01_easy", crop_to_gt=False).part(0.0, 0.005)
    assert len(head) == 184 and not head.gt.valid.any()
    with pytest.raises(InputError, match="no window of 100 samples with valid ground truth in chunks of 150"):
        make_chunks(head, 150, 100, 50, 10)
    assert make_chunks(head, 150, 100, 50, 10, allow_empty=True) is None
    # a sequence shorter than one chunk: no chunk fits
    with pytest.raises(InputError, match="no window of 500 samples"):
        make_chunks(seq, len(seq) + 50, 500, 50, 50)
    assert make_chunks(seq, len(seq) + 50, 500, 50, 50, allow_empty=True) is None


def test_gt_rotation_fills_the_ground_truth_rotation_of_every_chunk_sample(short_chunks):
    seq, chunks = short_chunks
    offsets = chunk_origins(chunks, seq, sample_index(seq))
    n = chunks.dt.shape[1]
    assert chunks.rotation.shape == (len(chunks), n, 3, 3)
    want = seq.gt.rot[offsets[:, None] + np.arange(n)]
    np.testing.assert_allclose(chunks.rotation.double().numpy(), want, atol=1e-7)
    assert make_chunks(seq, 1500, 500, 50, 50, context=18).rotation is None
    # with it velocity and position are integrated with the ground truth's rotation: the gyro does not reach them
    gravity = torch.einsum("bnji,j->bni", torch.as_tensor(want), torch.as_tensor(seq.gravity))
    gravity_imu = chunks.gravity_imu[:, chunks.context :].double()
    torch.testing.assert_close(gravity_imu, gravity.to(gravity_imu.dtype), rtol=0, atol=1e-5)
    dens = torch.full(chunks.gyro[:, chunks.context :].shape, 1e-6)
    raw = Correction(chunks.gyro[:, chunks.context :], chunks.acc[:, chunks.context :], None, None, dens, dens)
    spun = Correction(raw.gyro + 0.3, raw.acc, None, None, dens, dens)
    first, _ = chunks.errors(raw, dens, dens)
    second, _ = chunks.errors(spun, dens, dens)
    valid = chunks.valid
    torch.testing.assert_close(first[valid][..., 3:], second[valid][..., 3:], rtol=1e-9, atol=1e-9)
    assert (first[valid][..., :3] - second[valid][..., :3]).abs().max() > 0.1


@pytest.mark.parametrize(
    "weights", [LossWeights(), LossWeights(rotation=2.0, position=0.5, velocity=1.5, covariance_by_block=True)]
)
def test_masked_loss_is_the_loss_of_the_valid_windows_alone(flight_errors, weights):
    chunks, chunk_errors, chunk_var, _, window_errors, window_var, _ = flight_errors
    mask = chunks.mask
    assert not mask.all()  # the windows the moved-back chunk shares hold identity truth: they must not count
    masked = total_loss(chunk_errors, chunk_var, weights, mask)
    alone = total_loss(chunk_errors[mask], chunk_var[mask], weights)
    assert masked.dtype == F64 and abs(float(masked - alone)) <= 1e-12 * abs(float(alone))
    # ... the loss of make_windows' errors of those windows (in the chunks' order)
    per_window = total_loss(window_errors, window_var, weights)
    assert abs(float(masked - per_window)) <= 1e-12 * abs(float(per_window))
    unmasked = total_loss(chunk_errors, chunk_var, weights)
    assert abs(float(unmasked - alone)) > 1e-3 * abs(float(alone))


def test_training_on_chunks_lowers_the_loss(mh01):
    torch.manual_seed(0)
    train = make_chunks(mh01.part(0.0, 0.3), 1500, 500, 50, 50, context=18)
    val = make_chunks(mh01.part(0.3, 0.4), 1500, 500, 50, 50, context=18)
    assert len(train) >= 8 and not train.valid.all()
    model = AirImuNet(gru_sizes=(16, 16))
    trainer = Trainer(model, train, val, batch_size=2, seed=0)
    first, second = trainer.epoch(), trainer.epoch()
    for entry in (first, second):
        assert np.isfinite(entry.train_loss) and np.isfinite(entry.val_loss) and entry.train_loss > 0
    assert second.train_loss < first.train_loss


def test_the_validation_loss_takes_the_covariance_term_when_asked(mh01):
    """``train.val_covariance`` (the official AirIMU's test loss): the validation loss is the training loss's
    formula, covariance likelihood included, so it differs from the state loss alone; with the covariance loss off
    the flag changes nothing."""
    from learned_imu.training.train import window_loss

    torch.manual_seed(0)
    train = make_chunks(mh01.part(0.0, 0.2), 1500, 500, 50, 50, context=18)
    val = make_chunks(mh01.part(0.3, 0.4), 1500, 500, 50, 50, context=18)
    model = AirImuNet(gru_sizes=(16, 16)).eval()
    state = Trainer(model, train, val, batch_size=2, seed=0).validation_loss()
    full = Trainer(model, train, val, batch_size=2, seed=0, val_covariance=True)
    with torch.no_grad():
        expected = float(window_loss(model.eval(), val, full.weights, use_covariance=True))
    assert abs(full.validation_loss() - state) > 1e-3 * abs(state)
    assert full.validation_loss() == pytest.approx(expected, rel=1e-5)
    off = Trainer(model, train, val, batch_size=2, seed=0, use_covariance=False, val_covariance=True)
    assert off.validation_loss() == pytest.approx(state, rel=1e-12)

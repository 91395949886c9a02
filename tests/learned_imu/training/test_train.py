"""Training learns a simulated IMU's bias through the preintegrator; windows are cut correctly."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from airimu_core.sequence import GroundTruth, ImuSequence
from learned_imu.datasets.simulator import ImuErrorModel, simulate, simulate_with_truth
from learned_imu.evaluation.evaluate import evaluate
from learned_imu.network.model import AirImuNet, Correction, correct_sequence
from learned_imu.training.train import fit, fit_noise_scales, scale_noise
from learned_imu.training.windows import make_windows

# constant turn-on biases (0.5 deg/s, 0.05 m/s^2 one-sigma) and light white noise
BIASED = ImuErrorModel(1e-4, 1e-3, 0.0, 0.0, np.radians(0.5), 0.05)


def test_windows_start_on_ground_truth_and_supervise_every_kth_sample():
    seq = simulate("drone", duration_s=10.0, seed=0)
    windows = make_windows(seq, length=200, every=50, dtype=torch.float64)
    assert len(windows) == 9 and windows.targets.pos.shape == (9, 4, 3)
    assert torch.equal(windows.start.pos[1], torch.as_tensor(seq.gt.pos[200]))
    assert torch.equal(windows.targets.pos[1, 0], torch.as_tensor(seq.gt.pos[250]))  # after samples 200..249
    with pytest.raises(ValueError, match="every <= length"):
        make_windows(seq, length=200, every=300)


def test_context_windows_feed_history_to_the_network_but_integrate_only_the_window():
    seq = simulate("drone", duration_s=10.0, seed=0)
    plain = make_windows(seq, length=180, every=45, stride=180, dtype=torch.float64)
    windows = make_windows(seq, length=180, every=45, stride=180, dtype=torch.float64, context=18)
    assert windows.gyro.shape[1:] == (198, 3) and windows.dt.shape[1:] == (180,)
    assert torch.equal(windows.start.pos[0], torch.as_tensor(seq.gt.pos[18]))  # the first window starts after it
    assert torch.equal(windows.gyro[1, 18:], torch.as_tensor(seq.gyro[198:378]))
    assert torch.equal(windows.gyro[1, :18], torch.as_tensor(seq.gyro[180:198]))
    # with the receptive field as context (18 samples, block-aligned) a window's output is the streamed output of the
    # whole sequence at those samples: nothing in it comes from the network's zero padding
    torch.manual_seed(0)
    model = AirImuNet(conv_channels=(8, 16), use_gru=False).double().eval()
    with torch.no_grad():
        model.gyro_cov_decoder[-1].weight.normal_()  # a noise head that depends on its input
        out = windows.correct(model)
        whole = correct_sequence(model, torch.as_tensor(seq.gyro), torch.as_tensor(seq.acc))
    assert out.gyro_cov.shape == (len(windows), 180, 3)
    torch.testing.assert_close(out.gyro_cov[1], whole.gyro_cov[198:378])
    torch.testing.assert_close(out.gyro[1], whole.gyro[198:378])
    with torch.no_grad():  # without the context the first block differs
        first = plain.correct(model).gyro_cov[1, :9]
    assert not torch.allclose(first, whole.gyro_cov[180:189], rtol=1e-3, atol=0.0)
    with pytest.raises(ValueError, match="context"):
        make_windows(seq, length=200, every=50, context=-1)


def stretch(sim, first: int, last: int) -> ImuSequence:
    """Samples [first, last) of a simulated sequence, as a sequence of its own."""
    seq, gt = sim.sequence, sim.sequence.gt
    part = slice(first, last)
    return ImuSequence(
        name=f"{seq.name}[{first}:{last}]",
        t=seq.t[part],
        gyro=seq.gyro[part],
        acc=seq.acc[part],
        gravity=seq.gravity,
        gt=GroundTruth(gt.rot[part], gt.pos[part], gt.vel[part], gt.valid[part]),
    )


@pytest.mark.slow
def test_training_learns_the_bias_and_generalises_to_unseen_motion():
    torch.manual_seed(0)
    sim = simulate_with_truth("drone", duration_s=80.0, error_model=BIASED, seed=1)
    train_seq, val_seq = stretch(sim, 0, 12000), stretch(sim, 12000, 16000)  # 60 s to train, 20 s unseen
    train = make_windows(train_seq, length=200, every=50)
    val = make_windows(val_seq, length=200, every=50)
    model = AirImuNet(use_gru=False)
    history = fit(model, train, val, epochs=25, batch_size=8, lr=1e-2, seed=0)
    assert history[-1].train_loss < 0.2 * history[0].train_loss
    assert history[-1].val_loss < 0.05 * history[0].val_loss  # state loss on the unseen 20 s: 0.019 -> 0.00013
    corrected = correct_sequence(
        model.eval(),
        torch.as_tensor(val_seq.gyro, dtype=torch.float32),
        torch.as_tensor(val_seq.acc, dtype=torch.float32),
    )
    raw = evaluate(val_seq, 1.0)
    learned = evaluate(val_seq, 1.0, gyro=corrected.gyro.double().numpy(), acc=corrected.acc.double().numpy())
    assert learned.roe_deg < 0.3 * raw.roe_deg  # measured 0.370 -> 0.014 deg over 1 s
    learned_bias = -corrected.d_gyro.mean(dim=0).double().numpy()  # correction = -bias
    np.testing.assert_allclose(learned_bias, sim.gyro_bias[0], rtol=0.15)


class _ConstantNoise(torch.nn.Module):
    """A stand-in model: no corrections, the given constant noise densities."""

    def __init__(self, gyro_density: float, acc_density: float):
        super().__init__()
        self.gyro_density, self.acc_density = gyro_density, acc_density

    def forward(self, gyro, acc, gravity_imu=None):
        zero = torch.zeros_like(gyro)
        gyro_cov = torch.as_tensor(self.gyro_density, dtype=gyro.dtype).expand_as(gyro)
        acc_cov = torch.as_tensor(self.acc_density, dtype=acc.dtype).expand_as(acc)
        return Correction(gyro, acc, zero, zero, gyro_cov, acc_cov)


@pytest.mark.slow
def test_noise_scales_fitted_on_held_out_windows_recover_a_misstated_noise():
    """White noise only, the stand-in's densities 4x too small (gyro) and 9x too large (acc): the fitted scales
    undo both to within the sampling error of 150 windows, and then the NSE of every block is about 1."""
    error_model = ImuErrorModel(3e-3, 3e-2, 0.0, 0.0, 0.0, 0.0)
    sim = simulate_with_truth("drone", duration_s=150.0, error_model=error_model, seed=2)
    windows = make_windows(sim.sequence, length=200, every=50, dtype=torch.float64)
    gyro_density, acc_density = error_model.noise_densities()
    model = _ConstantNoise(gyro_density / 4, acc_density * 9)
    gyro_scale, acc_scale = fit_noise_scales(model, windows)
    assert gyro_scale == pytest.approx(4.0, rel=0.15) and acc_scale == pytest.approx(1 / 9, rel=0.15)


def test_scale_noise_multiplies_the_output_densities_exactly():
    model = AirImuNet(conv_channels=(8,), gru_sizes=(8,), decoder_hidden=8).eval()
    gyro, acc = torch.randn(1, 90, 3), torch.randn(1, 90, 3)
    with torch.no_grad():
        before = model(gyro, acc)
        scale_noise(model, 2.5, 0.3)
        after = model(gyro, acc)
    assert torch.allclose(after.gyro_cov, 2.5 * before.gyro_cov, rtol=1e-5)
    assert torch.allclose(after.acc_cov, 0.3 * before.acc_cov, rtol=1e-5)
    assert torch.equal(after.gyro, before.gyro)
    with pytest.raises(ValueError, match="positive"):
        scale_noise(model, 0.0, 1.0)

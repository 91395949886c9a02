"""Training learns a simulated IMU's bias through the preintegrator; windows are cut correctly."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from learned_imu.evaluate import evaluate
from learned_imu.model import AirImuNet, correct_sequence
from learned_imu.simulator import ImuErrorModel, simulate, simulate_with_truth
from learned_imu.train import fit
from learned_imu.windows import make_windows

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


def test_training_learns_the_bias():
    torch.manual_seed(0)
    train_seq = simulate("drone", duration_s=60.0, error_model=BIASED, seed=1)
    # same IMU (same seed -> same biases), a different stretch of flight for validation
    val_sim = simulate_with_truth("drone", duration_s=80.0, error_model=BIASED, seed=1)
    val_seq = val_sim.sequence
    train = make_windows(train_seq, length=200, every=50)
    val = make_windows(val_seq, length=200, every=50, stride=200)
    model = AirImuNet(use_gru=False)
    history = fit(model, train, val, epochs=25, batch_size=8, lr=1e-2, seed=0)
    assert history[-1].train_loss < 0.2 * history[0].train_loss
    corrected = correct_sequence(
        model.eval(),
        torch.as_tensor(val_seq.gyro, dtype=torch.float32),
        torch.as_tensor(val_seq.acc, dtype=torch.float32),
    )
    raw = evaluate(val_seq, 1.0)
    learned = evaluate(val_seq, 1.0, gyro=corrected.gyro.double().numpy(), acc=corrected.acc.double().numpy())
    assert learned.roe_deg < 0.3 * raw.roe_deg  # measured 0.372 -> 0.020 deg over 1 s
    learned_bias = -corrected.d_gyro.mean(dim=0).double().numpy()  # correction = -bias
    np.testing.assert_allclose(learned_bias, val_sim.gyro_bias[0], rtol=0.15)

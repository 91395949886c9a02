"""Deployable model: the exported streaming step (ONNX through onnxruntime, TorchScript) equals the PyTorch model
chunk by chunk, runs without this package, and bad requests fail with errors that say what is wrong.

Tolerance: ``assert_close(rtol=1e-5, atol=1e-5)`` on corrected samples and states, i.e. |a - b| <= 1e-5 + 1e-5 |b|,
and a relative 1e-5 alone (atol 0) on the noise densities, whose values (~1e-8 rad^2/s) an absolute 1e-5 would not
test.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

from airimu_core.errors import DataError, InputError
from learned_imu.config import ModelConfig
from learned_imu.network.deploy import StreamingStep, export_checkpoint, export_model
from learned_imu.network.model import AirImuNet, correct_sequence
from tests.helpers import write_checkpoint

ort = pytest.importorskip("onnxruntime")  # the deploy extra; part of the test extra too

SIZES = {"conv_channels": (8, 16), "gru_sizes": (16, 24), "decoder_hidden": 16}  # small: fast export and tests
BLOCK = 9  # stride 3, two convolutions
CHUNKS = (9, 27, 90, 18)  # samples per call: block multiples of several lengths (the export traced 18)
TOL = {"rtol": 1e-5, "atol": 1e-5}
DENSITY_TOL = {"rtol": 1e-5, "atol": 0.0}


def random_model(use_gru: bool, seed: int = 0) -> AirImuNet:
    """A small model with non-zero output layers and non-trivial BatchNorm statistics (an untrained model passes
    the raw IMU through, which would hide a wrong correction)."""
    torch.manual_seed(seed)
    model = AirImuNet(use_gru=use_gru, **SIZES)
    with torch.no_grad():
        for decoder in (model.acc_decoder, model.gyro_decoder, model.acc_cov_decoder, model.gyro_cov_decoder):
            torch.nn.init.normal_(decoder[-1].weight, std=0.5)
            torch.nn.init.normal_(decoder[-1].bias, std=0.5)
        for conv in model.convs:
            conv[1].running_mean.normal_(std=0.5)
            conv[1].running_var.uniform_(0.5, 2.0)
    return model.eval()


def samples(n: int, batch: int, seed: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    gyro = 0.5 * torch.randn(batch, n, 3, generator=gen)
    acc = torch.randn(batch, n, 3, generator=gen) + torch.tensor([0.0, 0.0, 9.81])
    return gyro, acc


def onnx_session(path) -> ort.InferenceSession:
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1  # the test machine is shared
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def zero_state(session, batch: int) -> dict[str, np.ndarray]:
    """The exported step's initial state, from the input declarations alone (as a user without torch would)."""
    return {
        i.name: np.zeros([batch if d == "batch" else d for d in i.shape], np.float32) for i in session.get_inputs()[2:]
    }


def run_onnx(session, gyro: np.ndarray, acc: np.ndarray, chunks) -> tuple[list[np.ndarray], dict]:
    """Stream (B, N, 3) arrays through the exported step in ``chunks``; the four outputs over N and the last state."""
    state_names = [i.name for i in session.get_inputs()][2:]
    state = zero_state(session, gyro.shape[0])
    outs, start = [], 0
    for n in chunks:
        result = session.run(None, {"gyro": gyro[:, start : start + n], "acc": acc[:, start : start + n], **state})
        outs.append(result[:4])
        state = dict(zip(state_names, result[4:], strict=True))
        start += n
    return [np.concatenate([o[k] for o in outs], axis=1) for k in range(4)], state


def stream_reference(model: AirImuNet, gyro: torch.Tensor, acc: torch.Tensor, chunks):
    """``AirImuNet.stream`` over the same chunks: the four outputs and the last state (flattened as exported)."""
    state, outs, start = model.initial_state(gyro.shape[0]), [], 0
    with torch.no_grad():
        for n in chunks:
            out, state = model.stream(gyro[:, start : start + n], acc[:, start : start + n], state)
            assert state.pending_gyro.shape[1] == 0  # block multiples: nothing held back
            outs.append((out.gyro, out.acc, out.gyro_cov, out.acc_cov))
            start += n
    return [torch.cat([o[k] for o in outs], dim=1) for k in range(4)], [*state.conv_history, *state.gru_hidden]


def assert_outputs_close(actual, expected) -> None:
    for k, (a, e) in enumerate(zip(actual, expected, strict=True)):
        tol = DENSITY_TOL if k >= 2 else TOL
        torch.testing.assert_close(torch.as_tensor(a), e, **tol, msg=lambda m, k=k: f"output {k}: {m}")


@pytest.fixture(scope="module", params=[True, False], ids=["gru", "cnn_only"])
def exported(request, tmp_path_factory):
    """One model per variant, exported once to both formats."""
    model = random_model(use_gru=request.param)
    folder = tmp_path_factory.mktemp("deploy")
    return model, export_model(model, folder / "m.onnx", "onnx"), export_model(model, folder / "m.pt", "torchscript")


@pytest.mark.slow
def test_onnx_streaming_equals_pytorch_stream_and_correct_sequence(exported):
    model, onnx_path, _ = exported
    n = sum(CHUNKS)
    gyro, acc = samples(n, batch=3)
    session = onnx_session(onnx_path)
    outs, state = run_onnx(session, gyro.numpy(), acc.numpy(), CHUNKS)
    expected, expected_state = stream_reference(model, gyro, acc, CHUNKS)
    assert_outputs_close(outs, expected)
    for a, e in zip(state.values(), expected_state, strict=True):
        torch.testing.assert_close(torch.as_tensor(a), e, **TOL)
    # The corrections are not trivial (so the comparison tests the network), and one pass agrees too.
    assert (torch.as_tensor(outs[0]) - gyro).abs().max() > 1e-3
    whole = correct_sequence(model, gyro[1], acc[1])
    assert_outputs_close([o[1] for o in outs], [whole.gyro, whole.acc, whole.gyro_cov, whole.acc_cov])


@pytest.mark.slow
def test_onnx_stream_end_padded_to_a_block_equals_the_flushed_stream(exported):
    model, onnx_path, _ = exported
    n = 4 * BLOCK + 5  # the last block is partial: pad it with the last sample, drop the padding's outputs
    gyro, acc = samples(n, batch=1, seed=2)
    pad = (-n) % BLOCK
    padded = [torch.cat([x, x[:, -1:].expand(-1, pad, -1)], dim=1).numpy() for x in (gyro, acc)]
    outs, _ = run_onnx(onnx_session(onnx_path), *padded, [2 * BLOCK, n + pad - 2 * BLOCK])
    whole = correct_sequence(model, gyro[0], acc[0], chunk=7)
    assert_outputs_close([o[0, :n] for o in outs], [whole.gyro, whole.acc, whole.gyro_cov, whole.acc_cov])


@pytest.mark.slow
def test_torchscript_streaming_equals_pytorch_stream(exported):
    model, _, script_path = exported
    step = torch.jit.load(str(script_path))
    assert step.block == BLOCK
    gyro, acc = samples(sum(CHUNKS), batch=2)
    histories, hidden = step.initial_state(2)
    outs, start = [], 0
    with torch.no_grad():
        for n in CHUNKS:
            *out, histories, hidden = step(gyro[:, start : start + n], acc[:, start : start + n], histories, hidden)
            outs.append(out)
            start += n
    expected, expected_state = stream_reference(model, gyro, acc, CHUNKS)
    assert_outputs_close([torch.cat([o[k] for o in outs], dim=1) for k in range(4)], expected)
    for a, e in zip([*histories, *hidden], expected_state, strict=True):
        torch.testing.assert_close(a, e, **TOL)


@pytest.mark.slow
def test_onnx_runs_without_torch_or_this_package(exported, tmp_path):
    model, onnx_path, _ = exported
    gyro, acc = samples(2 * BLOCK, batch=1, seed=3)
    np.savez(tmp_path / "in.npz", gyro=gyro.numpy(), acc=acc.numpy())
    code = (
        "import sys, numpy as np, onnxruntime as ort\n"
        f"s = ort.InferenceSession({str(onnx_path)!r}, providers=['CPUExecutionProvider'])\n"
        f"x = dict(np.load({str(tmp_path / 'in.npz')!r}))\n"
        "state = {i.name: np.zeros([1 if d == 'batch' else d for d in i.shape], np.float32)"
        " for i in s.get_inputs()[2:]}\n"
        "out = s.run(['gyro_corrected', 'acc_cov'], {**x, **state})\n"
        f"np.savez({str(tmp_path / 'out.npz')!r}, gyro=out[0], acc_cov=out[1])\n"
        "print('LOADED:', sorted(m for m in ('torch', 'learned_imu') if m in sys.modules))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "LOADED: []" in result.stdout
    out = np.load(tmp_path / "out.npz")
    whole = correct_sequence(model, gyro[0], acc[0])
    torch.testing.assert_close(torch.as_tensor(out["gyro"][0]), whole.gyro, **TOL)
    torch.testing.assert_close(torch.as_tensor(out["acc_cov"][0]), whole.acc_cov, **DENSITY_TOL)


@pytest.mark.slow
def test_onnx_names_axes_and_metadata(exported):
    model, onnx_path, _ = exported
    session = onnx_session(onnx_path)
    inputs = {i.name: i.shape for i in session.get_inputs()}
    outputs = [o.name for o in session.get_outputs()]
    state = ["conv_history_0", "conv_history_1"] + (["gru_hidden_0", "gru_hidden_1"] if len(model.grus) else [])
    assert list(inputs) == ["gyro", "acc", *state]
    assert outputs == ["gyro_corrected", "acc_corrected", "gyro_cov", "acc_cov", *(f"next_{s}" for s in state)]
    assert inputs["gyro"] == ["batch", "samples", 3]
    assert inputs["conv_history_1"] == ["batch", 8, 4]  # (B, C, kernel - stride)
    if len(model.grus):
        assert inputs["gru_hidden_1"] == [1, "batch", 24]
    meta = session.get_modelmeta().custom_metadata_map
    assert meta["block"] == str(BLOCK) and "rad^2/s" in meta["units"]


@pytest.mark.slow
def test_chunk_that_is_not_a_block_multiple_is_refused(exported):
    model, onnx_path, script_path = exported
    gyro, acc = samples(BLOCK + 1, batch=1)
    step = torch.jit.load(str(script_path))
    with pytest.raises(torch.jit.Error, match=f"multiple of {BLOCK} samples"):
        step(gyro, acc, *step.initial_state(1))
    session = onnx_session(onnx_path)
    with pytest.raises(Exception, match="out of data bounds|Non-zero status"):
        session.run(None, {"gyro": gyro.numpy(), "acc": acc.numpy(), **zero_state(session, 1)})


def test_streaming_step_in_python_equals_stream():
    model = random_model(use_gru=True, seed=4)
    step = StreamingStep(model)
    gyro, acc = samples(3 * BLOCK, batch=2)
    with torch.no_grad():
        *out, _, _ = step(gyro, acc, *step.initial_state(2))
    expected, _ = stream_reference(model, gyro, acc, [3 * BLOCK])
    assert_outputs_close(out, expected)
    assert model.training is False and not step.training


def checkpoint(path, model: AirImuNet, remove_gravity: bool = False):
    return write_checkpoint(path, ModelConfig(**SIZES, use_gru=False), model.state_dict(), remove_gravity)


@pytest.mark.slow
def test_cli_exports_a_checkpoint_that_onnxruntime_runs(tmp_path):
    from typer.testing import CliRunner

    from airimu.cli import app

    model = random_model(use_gru=False, seed=5)
    ckpt = checkpoint(tmp_path / "best.pt", model)
    out = tmp_path / "deploy" / "airimu.onnx"
    result = CliRunner().invoke(app, ["export-model", "--checkpoint", str(ckpt), "--format", "onnx", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "written to" in result.output and out.name in result.output
    assert [p.name for p in out.parent.iterdir()] == ["airimu.onnx"]  # no temporary file left
    gyro, acc = samples(4 * BLOCK, batch=1)
    outs, _ = run_onnx(onnx_session(out), gyro.numpy(), acc.numpy(), [BLOCK, 3 * BLOCK])
    whole = correct_sequence(model, gyro[0], acc[0])
    assert_outputs_close([o[0] for o in outs], [whole.gyro, whole.acc, whole.gyro_cov, whole.acc_cov])


def test_bad_format_corrupt_checkpoint_and_gravity_model_give_clear_errors(tmp_path):
    from typer.testing import CliRunner

    from airimu.cli import app

    model = random_model(use_gru=False)
    target = tmp_path / "m.onnx"
    target.write_bytes(b"previous export")
    with pytest.raises(InputError, match="format must be one of torchscript, onnx; got 'tflite'"):
        export_model(model, target, "tflite")
    ckpt = checkpoint(tmp_path / "ok.pt", model)
    result = CliRunner().invoke(app, ["export-model", "--checkpoint", str(ckpt), "--format", "onnnx", "--out", "x"])
    assert result.exit_code != 0 and "got 'onnnx'" in str(result.exception)

    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"\x00not a checkpoint")
    with pytest.raises(DataError, match="corrupt.pt.*not a readable torch checkpoint"):
        export_checkpoint(corrupt, target, "onnx")
    gravity = checkpoint(tmp_path / "gravity.pt", model, remove_gravity=True)
    with pytest.raises(DataError, match="gravity.pt: field 'config.train.remove_gravity'.*ground truth"):
        export_checkpoint(gravity, target, "torchscript")
    assert target.read_bytes() == b"previous export"  # failed exports leave the previous file as it was

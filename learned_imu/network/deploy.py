"""A trained ``AirImuNet`` as a file that runs without this package: TorchScript or ONNX, one streaming step.

The exported graph is ``StreamingStep``: ``AirImuNet.stream`` for one chunk whose length is a whole number of
blocks (``model.block = stride ** len(conv_channels)`` samples, 9 for the default model), with everything that
``stream`` carries as explicit state tensors. Zero initial states followed by chunks of any lengths that are block
multiples give what ``stream`` and ``correct_sequence`` give for the same samples (to float32 round-off): the chunk
in, as many corrected samples out, nothing held back (so ``stream``'s pending samples are always empty here). To
end a stream whose length is not a block multiple, pad the last chunk to a whole block with copies of its last
sample and drop the outputs of the padding: that is exactly ``stream(flush=True)``.

Conventions (float32 throughout):

- Inputs ``gyro`` (B, M, 3) angular rate in rad/s and ``acc`` (B, M, 3) specific force in m/s^2, raw, IMU frame;
  M a positive multiple of ``block``. Another M is an error: TorchScript raises naming the block; ONNX Runtime
  fails without naming it, in a Gather node ("indices element out of data bounds") or, for M < block, a Conv node.
- Outputs ``gyro_corrected`` (B, M, 3) rad/s and ``acc_corrected`` (B, M, 3) m/s^2 (raw + learned correction, IMU
  frame); ``gyro_cov`` (B, M, 3) rad^2/s and ``acc_cov`` (B, M, 3) m^2/s^3: the diagonal noise as
  continuous-time densities (sigma^2), as ``gtsam.PreintegrationParams`` takes them (one sample's variance is
  density / dt).
- State, zeros before the first chunk: ``conv_history_{i}`` (B, C_i, kernel - stride), the last inputs of
  convolution ``i`` (none if kernel == stride); ``gru_hidden_{j}`` (1, B, H_j), the hidden state of GRU ``j``
  (none in the CNN-only model). The step returns them as ``next_conv_history_{i}`` and ``next_gru_hidden_{j}``,
  to be fed back with the next chunk.

ONNX (opset ``ONNX_OPSET``, one self-contained file): axes ``batch`` and ``samples`` (= block x blocks) are dynamic;
the file's metadata holds ``block``, the input and output names and the units. TorchScript: ``forward(gyro, acc,
conv_history: List[Tensor], gru_hidden: List[Tensor]) -> (gyro_corrected, acc_corrected, gyro_cov,
acc_cov, next_conv_history, next_gru_hidden)``, ``initial_state(batch)`` and the attribute ``block``
(torch 2.13 marks TorchScript deprecated and warns; ONNX is the format to keep).

Models trained with ``train.remove_gravity`` read gravity in the IMU frame from ground truth, which a deployed model
does not have: ``export_checkpoint`` refuses them (``DataError`` naming the checkpoint's field).
"""

# No ``from __future__ import annotations``: TorchScript reads StreamingStep's class-level annotations as types.
import copy
import logging
import warnings
from pathlib import Path

import torch
from torch import nn

from airimu_core.errors import DataError, DependencyError, InputError
from airimu_core.io import atomic_file
from learned_imu.network.model import LOG_DENSITY_LIMIT, AirImuNet

log = logging.getLogger(__name__)

FORMATS = ("torchscript", "onnx")
ONNX_OPSET = 18  # the exporter op library's own (torch 2.13 defaults to 20); onnxruntime >= 1.14 loads it
OUTPUT_NAMES = ("gyro_corrected", "acc_corrected", "gyro_cov", "acc_cov")
_EXAMPLE_BLOCKS = 2  # chunk length of the example that the ONNX export traces (> 1, so it is not specialised)


class StreamingStep(nn.Module):
    """One streaming step of ``model`` (a copy, in eval mode) with tensors only in and out; shapes, units and the
    state are in the module docstring."""

    block: int
    pad: int
    acc_input_scale_m_s2: float
    log_density_limit: float
    history_sizes: list[int]
    hidden_sizes: list[int]

    def __init__(self, model: AirImuNet):
        super().__init__()
        net = copy.deepcopy(model).float().eval()
        self.block, self.pad = net.block, net.pad
        self.acc_input_scale_m_s2 = float(net.acc_input_scale_m_s2)
        self.log_density_limit = LOG_DENSITY_LIMIT
        self.convs, self.grus = net.convs, net.grus
        self.acc_decoder, self.gyro_decoder = net.acc_decoder, net.gyro_decoder
        self.acc_cov_decoder, self.gyro_cov_decoder = net.acc_cov_decoder, net.gyro_cov_decoder
        for name in ("acc_scale", "gyro_scale", "log_init_acc_density", "log_init_gyro_density"):
            self.register_buffer(name, getattr(net, name).clone())
        self.history_sizes = [conv[0].in_channels for conv in net.convs] if net.pad > 0 else []
        self.hidden_sizes = [gru.hidden_size for gru in net.grus]
        self.eval()

    def forward(
        self, gyro: torch.Tensor, acc: torch.Tensor, conv_history: list[torch.Tensor], gru_hidden: list[torch.Tensor]
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, list[torch.Tensor], list[torch.Tensor]]:
        if gyro.shape[1] % self.block != 0 or gyro.shape[1] == 0:
            raise InputError(f"StreamingStep: chunk length must be a positive multiple of {self.block} samples")
        # Encoder, as AirImuNet.stream: each convolution continues from the last inputs of the previous chunk.
        x = torch.cat([acc / self.acc_input_scale_m_s2, gyro], dim=-1).transpose(1, 2)  # (B, 6, M)
        histories: list[torch.Tensor] = []
        for i, conv in enumerate(self.convs):
            if self.pad > 0:
                x = torch.cat([conv_history[i], x], dim=-1)
                histories.append(x[:, :, x.shape[-1] - self.pad :])
            x = conv(x)
        features = x.transpose(1, 2)  # (B, M / block, F)
        hidden: list[torch.Tensor] = []
        for j, gru in enumerate(self.grus):
            features, h = gru(features, gru_hidden[j])
            hidden.append(h)
        # Decoders once per block, then each block's value to its samples. By index, with the length taken from the
        # input: the dynamo exporter records the GRU's output length as the example's, so a reshape would freeze it.
        block_of_sample = torch.div(torch.arange(gyro.shape[1], device=gyro.device), self.block, rounding_mode="floor")
        d_acc = self.acc_decoder(features) * self.acc_scale
        d_gyro = self.gyro_decoder(features) * self.gyro_scale
        log_acc = self.acc_cov_decoder(features).clamp(-self.log_density_limit, self.log_density_limit)
        log_gyro = self.gyro_cov_decoder(features).clamp(-self.log_density_limit, self.log_density_limit)
        return (
            gyro + d_gyro.index_select(1, block_of_sample),
            acc + d_acc.index_select(1, block_of_sample),
            torch.exp(log_gyro + self.log_init_gyro_density).index_select(1, block_of_sample),
            torch.exp(log_acc + self.log_init_acc_density).index_select(1, block_of_sample),
            histories,
            hidden,
        )

    @torch.jit.export
    def initial_state(self, batch: int) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
        """Zero state before the first chunk (as ``AirImuNet.initial_state``): conv histories, GRU hidden states."""
        histories = [torch.zeros(batch, c, self.pad) for c in self.history_sizes]
        hidden = [torch.zeros(1, batch, h) for h in self.hidden_sizes]
        return histories, hidden

    def state_names(self) -> tuple[list[str], list[str]]:
        """Names of the state inputs and of the matching outputs, in order."""
        names = [f"conv_history_{i}" for i in range(len(self.history_sizes))]
        names += [f"gru_hidden_{j}" for j in range(len(self.hidden_sizes))]
        return names, [f"next_{name}" for name in names]


def export_model(model: AirImuNet, path: str | Path, format: str) -> Path:
    """Write ``model``'s streaming step (``StreamingStep``, see the module docstring) to ``path`` atomically.

    ``format``: ``"torchscript"`` (``torch.jit.script``, load with ``torch.jit.load``) or ``"onnx"`` (dynamo
    exporter, needs the ``deploy`` extra: onnx, onnxscript; run with onnxruntime). Returns the path written.
    """
    if format not in FORMATS:
        raise InputError(f"export_model: format must be one of {', '.join(FORMATS)}; got {format!r}")
    step = StreamingStep(model)
    path = Path(path)
    if format == "torchscript":
        scripted = torch.jit.script(step)
        with atomic_file(path, "wb") as f:
            torch.jit.save(scripted, f)
    else:
        data = _onnx_bytes(step)
        with atomic_file(path, "wb") as f:
            f.write(data)
    log.info("exported the AirIMU streaming step (%s, block %d samples) to %s", format, step.block, path)
    return path


def export_checkpoint(checkpoint: str | Path, path: str | Path, format: str) -> Path:
    """``export_model`` of a checkpoint's model; refuses a model that reads gravity from ground truth."""
    from learned_imu.network.checkpoint import model_from_checkpoint

    if format not in FORMATS:  # before loading: a typo should not cost a checkpoint load
        raise InputError(f"export_checkpoint: format must be one of {', '.join(FORMATS)}; got {format!r}")
    model, config = model_from_checkpoint(checkpoint)
    if config.train.remove_gravity:
        raise DataError(
            checkpoint,
            "config.train.remove_gravity",
            "the model reads gravity in the IMU frame from ground truth, which a deployed model does not have; "
            "only models trained with remove_gravity false can be exported",
        )
    return export_model(model, path, format)


def _onnx_bytes(step: StreamingStep) -> bytes:
    """The ONNX model of ``step``: dynamic batch and chunk length, inputs and outputs named, metadata set."""
    try:
        import onnx
        import onnxscript  # noqa: F401  (the dynamo exporter's op library)
    except ImportError as error:
        raise DependencyError(
            f"ONNX export needs the packages onnx and onnxscript ({error}); pip install 'airimu[deploy]'"
        ) from error
    batch = 2
    gyro = torch.zeros(batch, _EXAMPLE_BLOCKS * step.block, 3)
    histories, hidden = step.initial_state(batch)
    batch_dim = torch.export.Dim("batch", min=1)
    samples_dim = step.block * torch.export.Dim("blocks", min=1)
    dynamic_shapes = (
        {0: batch_dim, 1: samples_dim},
        {0: batch_dim, 1: samples_dim},
        [{0: batch_dim} for _ in histories],
        [{1: batch_dim} for _ in hidden],
    )
    state_in, state_out = step.state_names()
    inputs, outputs = ["gyro", "acc", *state_in], [*OUTPUT_NAMES, *state_out]
    with warnings.catch_warnings():  # the exporter's internal deprecation and naming notices
        warnings.simplefilter("ignore")
        program = torch.onnx.export(
            step,
            (gyro, gyro.clone(), histories, hidden),
            dynamo=True,
            input_names=inputs,
            output_names=outputs,
            dynamic_shapes=dynamic_shapes,
            opset_version=ONNX_OPSET,
            external_data=False,
            # No graph optimisation: the optimiser folds the GRU's output length to the example's (a fixed-length
            # model); onnxruntime optimises the graph itself when it loads it.
            optimize=False,
            verbose=False,
        )
    proto = program.model_proto
    # The recorded intermediate shapes carry the example's GRU output length: drop them (they are optional) and
    # give the inputs and outputs axis names of our own.
    del proto.graph.value_info[:]
    for value in [*proto.graph.input, *proto.graph.output]:
        dims = value.type.tensor_type.shape.dim
        for axis, axis_name in _dynamic_axes(value.name).items():
            dims[axis].Clear()
            dims[axis].dim_param = axis_name
    onnx.helper.set_model_props(
        proto,
        {
            "block": str(step.block),
            "inputs": ",".join(inputs),
            "outputs": ",".join(outputs),
            "units": "gyro rad/s, acc m/s^2 (IMU frame); gyro_cov rad^2/s, acc_cov m^2/s^3 "
            "(continuous-time densities, sigma^2)",
        },
    )
    onnx.checker.check_model(proto)
    return proto.SerializeToString()


def _dynamic_axes(name: str) -> dict[int, str]:
    """The dynamic axes of an ONNX input or output, by name."""
    base = name.removeprefix("next_")
    if base in ("gyro", "acc", *OUTPUT_NAMES):
        return {0: "batch", 1: "samples"}
    return {1: "batch"} if base.startswith("gru_hidden_") else {0: "batch"}  # GRU (1, B, H), conv (B, C, pad)

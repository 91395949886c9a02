"""The network and its deployment: ``model`` (AirImuNet: corrections and per-sample noise), ``checkpoint`` (safe
save and load), ``inference`` (a model or a checkpoint applied to a sequence), ``deploy`` (TorchScript / ONNX)."""

"""Training: ``windows`` (supervised windows of sequences), ``losses``, ``train`` (the trainer, calibration and
noise scaling), ``experiment`` (run folders: config -> epochs -> checkpoints, resume), ``distributed``
(torchrun)."""

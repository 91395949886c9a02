"""Models installed with the package (``learned_imu.network.shipped``): loadable by name, with complete cards,
float16 weights, and listed by ``airimu models``."""

from __future__ import annotations

import pytest
import torch
from typer.testing import CliRunner

from airimu.cli import app
from airimu_core.errors import DataError, InputError
from learned_imu.network.checkpoint import load_checkpoint
from learned_imu.network.shipped import CARD_KEYS, SHIPPED_DIR, shipped_models, shipped_path


def test_every_shipped_model_loads_by_name_and_has_a_complete_card():
    cards = shipped_models()
    assert "euroc-motion" in cards
    for name, card in cards.items():
        assert set(CARD_KEYS) <= set(card) and card["kind"] in ("correction", "motion")
        checkpoint = load_checkpoint(name)  # by name, no path
        assert checkpoint.kind == card["kind"] and list(checkpoint.trainer) == ["model"]  # weights alone
        assert all(v.dtype == torch.float16 for v in checkpoint.trainer["model"].values() if v.is_floating_point())
        model = checkpoint.model(name) if card["kind"] == "correction" else checkpoint.motion_model(name)
        assert all(p.dtype == torch.float32 and torch.isfinite(p).all() for p in model.parameters())
        assert checkpoint.trained_on.rate_hz == pytest.approx(card["rate_hz"], rel=0.01)
        assert (SHIPPED_DIR / f"{name}.pt").stat().st_size < 2e6  # float16: a few hundred kB to 1 MB


def test_an_unknown_name_lists_the_shipped_models(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert shipped_path("../../etc/passwd") is None
    with pytest.raises(DataError, match="nor a shipped model of that name; shipped: .*euroc-motion"):
        load_checkpoint("eurocc")


def test_airimu_models_prints_the_cards():
    result = CliRunner().invoke(app, ["models"])
    assert result.exit_code == 0, result.output
    for name, card in shipped_models().items():
        assert name in result.output and card["licence"].split()[0] in result.output


def test_a_shipped_model_refuses_a_recording_of_another_rate():
    """The KITTI model (100 Hz) on a 200 Hz recording: refused, naming both rates, as any checkpoint is."""
    from learned_imu.datasets.simulator import simulate
    from learned_imu.network.checkpoint import model_from_checkpoint
    from learned_imu.network.inference import correct

    model, _ = model_from_checkpoint("kitti")
    with pytest.raises(InputError, match=r"sampled at 200.0 Hz, but the model was trained at 100.0 Hz"):
        correct(model, simulate("car", duration_s=5.0, rate_hz=200.0))

"""bench.anatomy_curve: the run configs of the curve's models."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench import anatomy_curve
from learner.config import load_config

SPEC = Path(__file__).resolve().parents[2] / "specs" / "train-anatomies.toml"


@pytest.mark.parametrize("kind", ["metapns", "pns"])
def test_run_config_gates_metapns_only(kind: str, monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    base = load_config(SPEC)
    assert base.model.capture_gate and base.train.gate_loss > 0  # the spec the curve trains from
    monkeypatch.setattr(anatomy_curve, "_train_subjects", lambda config, split: 128)
    config = anatomy_curve.run_config(base, tmp_path, 32, kind, steps=1280)
    assert config.model.kind == kind and config.data.split.train_count == 32
    assert config.train.epochs == 10 and config.out == str(tmp_path / f"{kind}-32")
    gated = kind == "metapns"
    assert config.model.capture_gate is gated and (config.train.gate_loss > 0) is gated

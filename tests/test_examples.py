"""The examples run on the tiny store and do what their docstrings say."""

from __future__ import annotations

import importlib.util
from pathlib import Path

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_simple_operator_learns_activation_times(tiny_store, capsys):
    history = _load("train_simple_operator").main([str(tiny_store), "--epochs", "5", "--device", "cpu"])
    assert len(history) == 5 and "validation_mse" in history[-1]
    # standardised targets: predicting the training mean scores about 1
    assert history[-1]["train_mse"] < 0.5 * history[0]["train_mse"] and history[-1]["validation_mse"] < 0.5
    assert "epoch 5" in capsys.readouterr().out

"""The evaluation API: the method registry, the evaluation setting, and reporting kept apart from running."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from learner.evaluate import EvalSetting
from learner.methods import BASELINES, METHODS, NEURAL, BaselineMethod, MethodContext, build_methods, register
from shared.errors import ConfigError, InputError
from shared.observation import Observation

ROOT = Path(__file__).resolve().parents[2]


def test_registry_names_every_compared_method() -> None:
    assert set(METHODS) == {"metaPNS", "PNS", "fs-bo", "vae-bo"} == set(NEURAL + BASELINES)


def test_build_methods_makes_fresh_baselines() -> None:
    context = MethodContext(budget=8, regions=2, seed=3)
    first, second = build_methods(("fs-bo", "fs-bo"), context)
    assert isinstance(first, BaselineMethod) and first is not second and first.baseline is not second.baseline
    assert [m.name for m in build_methods(BASELINES, context)] == ["fs-bo", "vae-bo"]
    with pytest.raises(ConfigError, match=r"unknown baseline\(s\) \['metaPNS'\]; choose from \['fs-bo', 'vae-bo'\]"):
        build_methods(("metaPNS",), context, among=BASELINES)
    with pytest.raises(ConfigError, match="unknown method"):
        build_methods(("ecg",), context)


def test_register_adds_a_method(monkeypatch) -> None:
    monkeypatch.setattr("learner.methods.METHODS", dict(METHODS))
    import learner.methods

    register("mean")(lambda context: "a method")
    assert "mean" in learner.methods.METHODS and "mean" not in METHODS
    assert build_methods(("mean",), MethodContext()) == ["a method"]


def test_eval_setting_of_a_config(tiny_store, tiny_config, tmp_path) -> None:
    config = tiny_config(tiny_store, tmp_path)
    setting = EvalSetting.of(config)
    assert setting == EvalSetting(Observation("surface", 0.0), 3, 10)
    assert EvalSetting.of(config, "electrodes", 0.02).observation == Observation("electrodes", 0.02)
    with pytest.raises(InputError, match="unknown observation set"):
        EvalSetting.of(config, "sock")


def test_reporting_is_apart_from_running() -> None:
    """The report module imports nothing that runs models, trains or evaluates."""
    tree = ast.parse((ROOT / "learner" / "benchmark_report.py").read_text())
    imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    imported |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    running = {"learner.benchmark", "learner.evaluate", "learner.methods", "learner.train.trainer", "torch"}
    assert not imported & running

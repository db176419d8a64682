"""bench.real_baselines: trained models join the baselines' table on the same folds."""

from __future__ import annotations

import types

import pytest

from bench import real_baselines
from learner.benchmark import BenchmarkConfig


def test_score_models_puts_each_model_first_under_its_reference(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = []

    def load_method(ref):
        method = types.SimpleNamespace(name="metapns")
        return method, types.SimpleNamespace(ref=ref), []

    def real_data(methods, setting, cfg, folds):
        calls.append((setting, folds))
        row = {"target": {"ref": setting}, "context": {}}
        return {"methods": {methods[0].name: row}, "folds": {methods[0].name: [{"fold": setting}]}}

    monkeypatch.setattr(real_baselines, "load_method", load_method)
    monkeypatch.setattr(real_baselines, "real_data", real_data)
    monkeypatch.setattr(real_baselines, "real_data_setting", lambda cfg, setting: setting)
    monkeypatch.setattr(real_baselines.EvalSetting, "of", staticmethod(lambda config: config.ref))
    result = {"methods": {"FS-BO": {"target": {}}}, "folds": {"FS-BO": [], "ceiling": []}}
    seconds = real_baselines.score_models(["anatomies", "runs/pns/best.pt"], BenchmarkConfig(), 0, result)
    assert list(result["methods"]) == ["anatomies", "runs/pns/best.pt", "FS-BO"]
    assert result["methods"]["runs/pns/best.pt"]["target"] == {"ref": "runs/pns/best.pt"}  # its own hierarchy
    assert list(result["folds"]) == ["anatomies", "runs/pns/best.pt", "FS-BO", "ceiling"]
    assert calls == [("anatomies", 0), ("runs/pns/best.pt", 0)] and set(seconds) == {"anatomies", "runs/pns/best.pt"}


def test_report_without_baselines_lists_the_models_alone() -> None:
    stats = {"mean": 0.5, "std": 0.1}
    row = {"target": {"mse": stats, "cc_spatial": stats, "cc_temporal": stats}, "context": {"cc_spatial": stats}}
    result = {"methods": {"anatomies": row}, "ceiling": row}
    text = real_baselines.report("header\n", result, [], {"anatomies": 12.04})
    assert text.startswith("header\n\n| method |") and "| anatomies |" in text and "noise-free truth" in text
    assert "first fit" not in text and text.endswith("- anatomies: 12.0 s for all its folds\n")

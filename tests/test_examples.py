"""The examples run, are valid and do what their docstrings say."""

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


def test_tissue_example_is_a_valid_setting_with_its_scars():
    from shared.config import load_toml
    from simgen.meshes import get_mesh
    from simgen.tissue import tissue_fields, tissue_spec_from_mapping

    spec = tissue_spec_from_mapping(load_toml(EXAMPLES / "scar.toml"))
    assert spec.name == "scar-lateral-and-sphere" and [s.region for s in spec.scars] == ["segments", "sphere"]
    label = tissue_fields(get_mesh("lv", 2000), spec).label
    assert (label == 2).any() and (label == 1).any() and (label == 0).any()


def test_observation_example_is_valid_and_what_its_script_writes(tmp_path, capsys):
    import numpy as np

    from learner.activation_maps import ApTemplate
    from learner.observations import observations_from_file
    from learner.pretrained import info

    shipped = observations_from_file(EXAMPLES / "observations.npz")
    k, frames, n = shipped.obs.shape
    assert (k, frames) == (3, 55) and shipped.observed.sum() == 64 and len(shipped.mesh.points) == n
    assert np.allclose(shipped.times, 0.6 * np.arange(1, 56))  # 7.74 ms apart, in model time units
    assert 0.9 < shipped.obs[:, -20:, shipped.observed].max() < 1.2  # u: about 1 where excited, noise 0.02
    maps = observations_from_file(EXAMPLES / "activation_maps.npz")
    assert maps.activation.shape == (3, n) and np.array_equal(maps.observed, shipped.observed)
    rendered = maps.at_frames(shipped.times, lambda: ApTemplate.from_dict(info("anatomies").config["ap_template"]))
    assert np.abs(rendered.obs - shipped.obs)[:, :, shipped.observed].mean() < 0.1  # measured 0.08: scars shorten APs
    args = [str(tmp_path / "observations.npz"), "--maps", str(tmp_path / "activation_maps.npz")]
    written = _load("write_observations").main(args)
    for name, path in zip(("observations.npz", "activation_maps.npz"), written):
        with np.load(EXAMPLES / name) as a, np.load(path) as b:
            assert sorted(a) == sorted(b) and all(np.array_equal(a[key], b[key], equal_nan=True) for key in a)

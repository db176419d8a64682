"""The shipped pretrained model: safetensors weights, config and card; by name everywhere; accurate on new hearts."""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from learner import pretrained
from learner.activation_maps import ApTemplate
from learner.checkpoint import load_checkpoint
from learner.cli import app
from learner.evaluate import EvalSpec, evaluate
from learner.metrics import mse
from learner.models.surrogate import MetaPNS
from learner.pretrained import shipped as shipped_models
from learner.store_view import StoreView
from learner.train.trainer import load_model
from shared.errors import InputError
from shared.reader import read_u

runner = CliRunner()
NAME = "anatomies"

#: Two hearts no shipped model saw (sampled with other seeds than specs/anatomies.toml's), a scar each,
#: 12 surface sites, the training store's frames and sock: 48 simulations of ~1,000 nodes.
NEW_HEARTS_SPEC = {
    "name": "new-hearts",
    "seed": 11,
    "tissue": ["healthy", "scar-septal-basal"],
    "meshes": [
        {"id": "lv", "source": "lv", "nodes": 1000, "shape": "random", "count": 1, "seed": 101},
        {"id": "biv", "source": "biv", "nodes": 1000, "shape": "random", "count": 1, "seed": 102},
    ],
    "sites": {"count": 12, "node_set": "surface", "method": "farthest"},
    "solver": {"frames": 55, "output_interval": 0.6},
    "output": {"chunk_sites": 12, "sock_electrodes": 247},
}


@pytest.mark.parametrize("name", pretrained.names())
def test_every_shipped_model_is_safetensors_weights_with_config_and_card(name):
    shipped = pretrained.info(name)
    raw = shipped.weights.read_bytes()
    assert len(raw) < 16 * 2**20  # small enough to ship in the package
    size = int.from_bytes(raw[:8], "little")  # safetensors: header length, JSON header, raw tensor bytes
    header = json.loads(raw[8 : 8 + size])
    tensors = {k: v for k, v in header.items() if k != "__metadata__"}
    assert {v["dtype"] for v in tensors.values()} <= {"F32", "F16"}
    assert sum(int(np.prod(v["shape"])) for v in tensors.values()) == shipped.parameters
    assert hashlib.sha256(raw).hexdigest() == shipped.config["weights"]["sha256"]
    config = shipped.config
    assert config["hierarchy"]["levels"] == config["config"]["model"]["levels"]
    assert len(config["times"]) == config["frames"] == 55
    assert set(config["splits"]) == {"train", "validation", "test"}
    card = shipped.card.read_text()
    for fact in (config["training"]["store_spec_hash"], config["training"]["spec"], "Intended use", "Licence"):
        assert fact in card
    # the card's figures, version and date, machine-readable beside the weights and the same as the card's table
    metrics = config["card"]["metrics"]
    assert config["card"]["version"] == importlib.metadata.version("metapns") and config["card"]["date"]
    for figure in (metrics["unseen_sampled_hearts"]["cc_spatial"]["mean"], metrics["real_heart_sock"]["mse"]["mean"]):
        assert f"{figure:.3f}"[:5] in card or f"{figure:.4f}" in card
    template = ApTemplate.from_dict(config["ap_template"])
    assert template.u[0] == pytest.approx(0.0, abs=1e-3) and template.u.max() > 0.95  # rest, then an action potential


def test_load_returns_a_ready_metapns_and_the_name_is_a_checkpoint():
    model = pretrained.load(NAME)
    assert isinstance(model, MetaPNS) and not model.training and model.frames == 55
    loaded, config, ckpt = load_model(NAME)
    assert ckpt["shipped"] == NAME and config.model.kind == "metapns"
    assert all((a == b).all() for a, b in zip(model.state_dict().values(), loaded.state_dict().values()))
    with pytest.raises(InputError, match="is a shipped model, not a 'personalized' file"):
        load_checkpoint(NAME, kind="personalized")
    with pytest.raises(InputError, match=f"nor a shipped model: .*{NAME}"):
        load_checkpoint("no-such-model")


def test_models_lists_the_shipped_models():
    result = runner.invoke(app, ["models"], terminal_width=200)
    assert result.exit_code == 0, result.output
    assert NAME in result.output and "metapns" in result.output


def test_config_files_take_a_shipped_name(tiny_store, tiny_toml, tmp_path):
    """A train config's ``init`` and a benchmark config's checkpoints name a shipped model as the CLI does."""
    from learner.benchmark import load_benchmark_config
    from learner.config import load_config
    from learner.train.trainer import Trainer

    train_toml = tmp_path / "train.toml"
    train_toml.write_text(tiny_toml(tiny_store, train=f'epochs = 1\ninit = "{NAME}"'))
    cfg = load_config(train_toml)
    assert cfg.train.init == NAME
    trainer = Trainer(cfg, progress=False)
    assert sorted(trainer.warm_start["copied"] + trainer.warm_start["fresh"]) == sorted(trainer.model.state_dict())
    bench_toml = tmp_path / "bench.toml"
    bench_toml.write_text(f'store = "{tiny_store}"\nmetapns = "{NAME}"\npns = "pns.pt"\n')
    bench = load_benchmark_config(bench_toml)
    assert bench.metapns == NAME and bench.pns == str(tmp_path / "pns.pt")
    (tmp_path / NAME).write_bytes(b"")  # a file of that name next to the config wins
    assert load_benchmark_config(bench_toml).metapns == str(tmp_path / NAME)


def test_damaged_weights_are_refused(tmp_path, monkeypatch):
    shutil.copytree(pretrained.info(NAME).folder, tmp_path / NAME)
    weights = tmp_path / NAME / pretrained.WEIGHTS
    raw = bytearray(weights.read_bytes())
    raw[-1] ^= 0xFF
    weights.write_bytes(bytes(raw))
    monkeypatch.setattr(shipped_models, "SHIPPED_DIR", tmp_path)
    with pytest.raises(InputError, match="is damaged"):
        pretrained.load(NAME)
    with pytest.raises(InputError, match="no shipped model named 'other' \\(shipped: anatomies"):
        pretrained.info("other")


def _rewritten(folder, tensors: dict | None = None, config: dict | None = None) -> None:
    """Rewrite a shipped folder's weights (with the digest of ``config``) and config.json, hashes updated:
    what a careless or hostile edit that also fixes the recorded SHA-256 leaves."""
    from safetensors.torch import load_file, save_file

    weights, path = folder / pretrained.WEIGHTS, folder / pretrained.CONFIG
    document = config or json.loads(path.read_text())
    save_file(
        tensors or load_file(weights), str(weights), metadata={"config_sha256": pretrained.config_digest(document)}
    )
    document["weights"]["sha256"] = pretrained.file_sha256(weights)
    path.write_text(json.dumps(document))


def test_the_model_is_checked_whole_config_weights_and_values(tmp_path, monkeypatch):
    from safetensors.torch import load_file

    folder = tmp_path / NAME
    shutil.copytree(pretrained.info(NAME).folder, folder)
    monkeypatch.setattr(shipped_models, "SHIPPED_DIR", tmp_path)
    config = json.loads((folder / pretrained.CONFIG).read_text())
    edited = {**config, "frames": 54}  # an edit of config.json after export
    (folder / pretrained.CONFIG).write_text(json.dumps(edited))
    with pytest.raises(InputError, match="config.json does not match model.safetensors: its content"):
        pretrained.load(NAME)
    card = {**config, "card": {**config["card"], "date": "2030-01-01"}}  # the card's figures are not signed
    (folder / pretrained.CONFIG).write_text(json.dumps(card))
    pretrained.load(NAME)
    tensors = load_file(folder / pretrained.WEIGHTS)
    first = sorted(tensors)[0]
    _rewritten(folder, {**tensors, first: tensors[first] * float("nan")}, config)
    with pytest.raises(InputError, match=f"1 weight tensor\\(s\\) hold NaN or inf, first '{first}'"):
        pretrained.load(NAME)
    wider = json.loads(json.dumps(config))
    wider["config"]["model"]["latent"] = 32  # a config that describes another model than the weights
    _rewritten(folder, tensors, wider)
    with pytest.raises(InputError, match="its weights do not fit the model its config describes"):
        load_model(NAME)


def test_a_damaged_shipped_model_is_one_line_on_the_command_line(tmp_path, monkeypatch):
    from safetensors.torch import load_file

    folder = tmp_path / NAME
    shutil.copytree(pretrained.info(NAME).folder, folder)
    monkeypatch.setattr(shipped_models, "SHIPPED_DIR", tmp_path)
    examples = Path(__file__).resolve().parents[2] / "examples"
    args = ["personalize", NAME, "--observations", str(examples / "observations.npz"), "--out", str(tmp_path / "p")]
    config = json.loads((folder / pretrained.CONFIG).read_text())
    (folder / pretrained.CONFIG).write_text(json.dumps({**config, "frames": 54}))
    edited = runner.invoke(app, args)
    tensors = load_file(folder / pretrained.WEIGHTS)
    first = sorted(tensors)[0]
    _rewritten(folder, {**tensors, first: tensors[first] * float("nan")}, config)
    nan = runner.invoke(app, args)
    for result, expected in ((edited, "does not match model.safetensors"), (nan, "hold NaN or inf")):
        assert result.exit_code == 2 and "Traceback" not in result.output, result.output
        errors = [line for line in result.output.splitlines() if line.startswith("error:")]
        assert len(errors) == 1 and expected in " ".join(result.output.split()), result.output


def test_export_writes_what_load_reads(tiny_store, tiny_toml, tmp_path, monkeypatch):
    cfg = tmp_path / "train.toml"
    cfg.write_text(tiny_toml(tiny_store, train="epochs = 1"))
    assert runner.invoke(app, ["train", str(cfg)]).exit_code == 0
    root = tmp_path / "shipped"
    args = ["export", str(tmp_path / "run" / "best.pt"), str(root / "tiny"), "--summary", "a tiny test model"]
    result = runner.invoke(app, [*args, "--spec", "train.toml"])
    assert result.exit_code == 0, result.output
    config = json.loads((root / "tiny" / pretrained.CONFIG).read_text())
    assert config["config"]["data"]["store"] == tiny_store.name and str(tmp_path) not in json.dumps(config)
    assert config["training"]["store_spec_hash"] == StoreView(tiny_store).attrs["spec_hash"]
    monkeypatch.setattr(shipped_models, "SHIPPED_DIR", root)
    trained, _, _ = load_model(tmp_path / "run" / "best.pt")
    shipped = pretrained.load("tiny")
    assert all((a == b).all() for a, b in zip(trained.state_dict().values(), shipped.state_dict().values()))
    result = runner.invoke(app, ["export", str(tmp_path / "run" / "best.pt"), str(root / "Bad Name"), "--summary", "x"])
    assert result.exit_code == 2 and "model name 'Bad Name'" in result.output


@pytest.fixture(scope="module")
def new_hearts(tmp_path_factory):
    from simgen.store import spec_from_mapping
    from simgen.store.runner import build

    store = tmp_path_factory.mktemp("new-hearts") / "new.zarr"
    build(spec_from_mapping(NEW_HEARTS_SPEC), store, workers=1)
    return store


def test_personalised_on_new_hearts_it_beats_the_mean_predictor(new_hearts):
    """3 surface-observed simulations personalise the shipped model to each new heart; 9 other sites are predicted.

    Measured (2-core AMD EPYC VM): target MSE 0.0215 and spatial CC 0.868 over the 4 subjects; the mean
    predictor (each frame's mean over every simulation and node of the subject, the truth included) reaches
    MSE 0.0833 and carries no spatial pattern (no CC).
    """
    spec = EvalSpec(subjects=tuple(StoreView(new_hearts).subjects), context=(3, 3), context_sets=1, max_targets=9)
    report = evaluate(NAME, new_hearts, spec)
    target = report.overall["target"]
    mean_predictor = []
    for subject in StoreView(new_hearts).subjects:
        u = read_u(new_hearts, subject)
        mean_predictor.append(mse(np.broadcast_to(u.mean(axis=(0, 2))[None, :, None], u.shape), u))
    assert target["mse"]["mean"] < 0.4 * np.mean(mean_predictor)
    assert target["cc_spatial"]["mean"] > 0.8

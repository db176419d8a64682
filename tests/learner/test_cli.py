"""End to end through the ``learner`` CLI: train, curves, evaluate, personalise, predict (with VTK)."""

from __future__ import annotations

import json

import meshio
import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from learner.cli import app
from learner.store_view import StoreView
from shared.reader import read_sites

runner = CliRunner()


@pytest.fixture(scope="module")
def trained(tiny_store, tiny_toml, tmp_path_factory):
    folder = tmp_path_factory.mktemp("cli")
    cfg = folder / "train.toml"
    cfg.write_text(tiny_toml(tiny_store, train="epochs = 2"))
    result = runner.invoke(app, ["train", str(cfg)])
    assert result.exit_code == 0, result.output
    assert "epoch    2" in result.output
    return folder


def test_train_on_a_missing_store_fails_before_making_the_run_folder(tiny_toml, tmp_path):
    cfg = tmp_path / "train.toml"
    cfg.write_text(tiny_toml(tmp_path / "missing.zarr"))
    result = runner.invoke(app, ["train", str(cfg)])
    assert result.exit_code == 2 and "missing.zarr is not a Zarr store" in " ".join(result.output.split())
    assert not (tmp_path / "run").exists()


def test_train_takes_a_seed_and_curves_plot_the_runs(trained):
    result = runner.invoke(
        app, ["train", str(trained / "train.toml"), "--seed", "3", "--epochs", "1", "--out", str(trained / "seed3")]
    )
    assert result.exit_code == 0, result.output
    assert json.loads((trained / "seed3" / "config.json").read_text())["train"]["seed"] == 3
    assert "\r" not in result.output and "epoch    1" in result.output  # not a terminal: plain lines, no bar
    png = trained / "curves.png"
    result = runner.invoke(app, ["curves", str(trained / "run"), str(trained / "seed3"), "--out", str(png)])
    assert result.exit_code == 0, result.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    result = runner.invoke(app, ["curves", str(trained / "eval-missing")])
    assert result.exit_code == 2 and "log.jsonl not found" in result.output


def test_evaluate_writes_json_and_markdown(trained, tiny_store):
    out = trained / "eval"
    result = runner.invoke(
        app,
        [
            "evaluate",
            str(trained / "run" / "best.pt"),
            str(tiny_store),
            "--out",
            str(out),
            "--sets",
            "2",
            "--max-targets",
            "3",
        ],
    )
    assert result.exit_code == 0, result.output
    report = json.loads((out / "evaluation.json").read_text())
    assert set(report["overall"]) == {"context", "target"}
    assert {"mse", "cc_spatial", "cc_temporal", "dc", "act_error_ms"} <= set(report["overall"]["target"])
    assert len(report["rows"]) > 0 and report["timing"]["predict_s_per_sim"] > 0
    table = [line for line in result.output.splitlines() if line.startswith("|")]  # not wrapped at 80 columns
    assert max(map(len, table)) > 80 and all(line.endswith("|") for line in table)
    assert all(line in (out / "evaluation.md").read_text() for line in table)
    assert "| target |" in (out / "evaluation.md").read_text()


def test_an_observation_mixture_trains_and_evaluates_on_its_first_set(tiny_store, tiny_toml, tmp_path):
    cfg = tmp_path / "mixed.toml"
    text = tiny_toml(tiny_store, train="epochs = 1")
    cfg.write_text(text.replace("targets = 4", 'targets = 4\nobserve = ["epicardium", "surface"]\nnoise_std = 0.02'))
    result = runner.invoke(app, ["train", str(cfg)])
    assert result.exit_code == 0, result.output
    assert json.loads((tmp_path / "run" / "config.json").read_text())["data"]["episodes"]["observe"] == [
        "epicardium",
        "surface",
    ]
    out = tmp_path / "eval"
    args = ["evaluate", str(tmp_path / "run" / "best.pt"), str(tiny_store), "--sets", "1", "--max-targets", "2"]
    result = runner.invoke(app, [*args, "--out", str(out)])
    assert result.exit_code == 0, result.output
    explicit = tmp_path / "eval-epicardium"
    result = runner.invoke(app, [*args, "--observe", "epicardium", "--out", str(explicit)])
    assert result.exit_code == 0, result.output
    report = lambda folder: json.loads((folder / "evaluation.json").read_text())["overall"]  # noqa: E731
    assert report(out) == report(explicit)


def test_personalize_then_predict_with_vtk(trained, tiny_store):
    sites = read_sites(tiny_store, "lv")
    person = trained / "p.pt"
    result = runner.invoke(
        app,
        [
            "personalize",
            str(trained / "run" / "best.pt"),
            "--out",
            str(person),
            "--store",
            str(tiny_store),
            "--subject",
            "lv-scar-apex",
            "--sites",
            f"{sites[0]}",
            "--site-xyz",
            ",".join(f"{v + 0.5:.3f}" for v in StoreView(tiny_store).mesh("lv").points[sites[3]]),
        ],
    )
    assert result.exit_code == 0, result.output
    saved = torch.load(person, weights_only=True)
    assert saved["kind"] == "personalized" and saved["context_sites"].tolist() == [sites[0], sites[3]]
    out = trained / "pred.npz"
    result = runner.invoke(
        app,
        [
            "predict",
            str(person),
            "--sites",
            f"{sites[5]}",
            "--out",
            str(out),
            "--vtk",
            str(trained / "vtk"),
            "--samples",
            "3",
        ],
    )
    assert result.exit_code == 0, result.output
    data = np.load(out)
    assert data["v_mv"].shape == (1, 12, 520) and data["spread_mv"].shape == (1, 12, 520)
    assert data["activation_spread_ms"].shape == (1, 520) and data["points"].shape == (520, 3)
    pvd = (trained / "vtk" / f"site-{sites[5]}.pvd").read_text()
    assert pvd.count("<DataSet") == 12 and 'timestep="' in pvd  # a time series with its times in ms
    mesh = meshio.read(trained / "vtk" / f"site-{sites[5]}_0011.vtu")
    assert {"V_mV", "u", "spread_mV", "activation_ms", "activation_spread_ms"} <= set(mesh.point_data)


def test_refined_personalisation_reports_the_steps_it_chose(trained, tiny_store):
    """``--refine-steps`` in personalize and evaluate: a maximum, the count chosen on held-out recordings."""
    sites = read_sites(tiny_store, "lv")
    common = ["--store", str(tiny_store), "--subject", "lv-scar-apex", "--sites", f"{sites[0]},{sites[3]}"]
    files, outputs = {}, {}
    for steps in (0, 10):
        files[steps] = trained / f"p-refined-{steps}.pt"
        args = ["personalize", str(trained / "run" / "best.pt"), "--out", str(files[steps]), *common]
        result = runner.invoke(app, [*args, "--refine-steps", str(steps)], terminal_width=200)
        assert result.exit_code == 0, result.output
        outputs[steps] = " ".join(result.output.split())
    plain, refined = (torch.load(files[s], weights_only=True) for s in (0, 10))
    taken = refined["refine_steps_taken"]
    assert refined["refine_steps"] == 10 and plain["refine_steps"] == 0 and 0 <= taken <= 10
    assert (f"refined in {taken} of up to 10 steps" if taken else "not refined") in outputs[10]
    assert "refined in" not in outputs[0] and "not refined" not in outputs[0]
    assert torch.equal(plain["c_mu"], refined["c_mu"]) == (taken == 0)
    assert torch.equal(plain["c_logvar"], refined["c_logvar"])
    out = trained / "eval-refined"
    args = ["evaluate", str(trained / "run" / "best.pt"), str(tiny_store), "--sets", "1", "--max-targets", "2"]
    result = runner.invoke(app, [*args, "--refine-steps", "10", "--out", str(out)])
    assert result.exit_code == 0, result.output


@pytest.mark.parametrize(
    "args, message",
    [
        (["--subject", "nobody", "--sites", "1"], "unknown subject"),
        (["--subject", "lv-healthy", "--sites", "999999"], "no simulation stimulated at node"),
        (["--subject", "lv-healthy", "--sites", ""], "give the context sites of subject 'lv-healthy'"),
        (["--subject", "lv-healthy", "--site-xyz", "1e4,0,0"], "no simulated site within 5 mm of site point"),
    ],
)
def test_personalize_refuses_bad_input(trained, tiny_store, args, message):
    result = runner.invoke(
        app,
        [
            "personalize",
            str(trained / "run" / "best.pt"),
            "--out",
            str(trained / "x.pt"),
            "--store",
            str(tiny_store),
            *args,
        ],
    )
    assert result.exit_code == 2 and message in result.output.replace("\n", " ")
    assert not (trained / "x.pt").exists()


def test_predict_refuses_unknown_nodes(trained, tiny_store):
    person = trained / "p2.pt"
    sites = read_sites(tiny_store, "lv")
    runner.invoke(
        app,
        [
            "personalize",
            str(trained / "run" / "best.pt"),
            "--out",
            str(person),
            "--store",
            str(tiny_store),
            "--subject",
            "lv-healthy",
            "--sites",
            f"{sites[1]}",
        ],
    )
    result = runner.invoke(app, ["predict", str(person), "--sites", "100000"])
    assert result.exit_code == 2 and "not nodes of the" in result.output

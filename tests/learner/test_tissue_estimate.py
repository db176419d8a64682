"""A personalised heart's tissue estimate: probabilities and CV over draws of c, its scores, files and command."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from learner.cli import app
from learner.personalized import PersonalizedHeart, personalize
from learner.tissue_estimate import ABNORMAL_THRESHOLD, TissueEstimate, tissue_scores
from learner.train.trainer import Trainer
from shared.errors import InputError
from shared.mesh import Mesh


@pytest.fixture(scope="module")
def heart_file(tiny_store, tiny_config, tmp_path_factory):
    """A heart personalised on 3 recordings of the tiny store's apex scar by a metaPNS with a tissue head."""
    from learner.observations import observations_from_store
    from learner.store_view import StoreView

    out = tmp_path_factory.mktemp("run")
    config = tiny_config(tiny_store, out, model={"tissue_head": True}, epochs=1, tissue_loss=0.1)
    Trainer(config, progress=False).fit()
    sites = [int(s) for s in StoreView(tiny_store).sites("lv")[:3]]
    path = out / "heart.pt"
    personalize(out / "last.pt", observations_from_store(tiny_store, "lv-scar-apex", sites, "surface"), path)
    return path


def test_estimate_averages_draws_of_c_and_reloads_the_same(heart_file):
    heart = PersonalizedHeart.load(heart_file)
    estimate = heart.tissue(samples=8, seed=3)
    n = heart.mesh.n_nodes
    assert estimate.abnormal_probability.shape == estimate.abnormal_spread.shape == (n,)
    assert np.all((estimate.abnormal_probability >= 0) & (estimate.abnormal_probability <= 1))
    assert estimate.cv_draws.shape == (8,) and estimate.cv > 0 and estimate.cv_spread > 0
    assert estimate.cv == pytest.approx(estimate.cv_draws.mean())
    np.testing.assert_array_equal(estimate.abnormal, estimate.abnormal_probability >= ABNORMAL_THRESHOLD)
    again = PersonalizedHeart.load(heart_file).tissue(samples=8, seed=3)
    np.testing.assert_array_equal(again.abnormal_probability, estimate.abnormal_probability)
    assert heart.tissue(samples=8, seed=4).cv != estimate.cv  # other draws
    with pytest.raises(InputError, match="between 2 and 10000"):
        heart.tissue(samples=1)


def test_scores_by_hand():
    mesh = Mesh(points=np.zeros((4, 3)), cells=np.array([[0, 1, 2, 3]]))
    estimate = TissueEstimate(
        np.array([0.9, 0.6, 0.2, 0.1], np.float32), np.zeros(4, np.float32), np.array([1.0, 1.2]), mesh
    )
    scores = tissue_scores(estimate, np.array([True, False, True, False]), cv=1.0)
    assert scores["tissue_dice"] == pytest.approx(2 * 1 / (2 + 2))  # estimate {0, 1}, truth {0, 2}
    assert scores["cv_error"] == pytest.approx(0.1)
    healthy = TissueEstimate(np.zeros(4, np.float32), np.zeros(4, np.float32), np.array([1.0]), mesh)
    assert np.isnan(tissue_scores(healthy, np.zeros(4, bool), 1.0)["tissue_dice"])
    with pytest.raises(InputError, match="nodes"):
        tissue_scores(estimate, np.zeros(3, bool), 1.0)


def test_tissue_command_writes_arrays_vtk_and_png(heart_file, tmp_path):
    import meshio

    args = ["tissue", str(heart_file), "--out", str(tmp_path / "t.npz"), "--vtk", str(tmp_path / "t.vtu")]
    result = CliRunner().invoke(app, [*args, "--png", str(tmp_path / "t.png"), "--samples", "4"])
    assert result.exit_code == 0, result.output
    assert "m/s" in result.output and "scar core or border zone" in result.output
    with np.load(tmp_path / "t.npz") as f:
        assert {"abnormal_probability", "cv_m_per_s", "cv_draws_m_per_s", "points", "cells"} <= set(f.files)
        n = len(f["points"])
    assert meshio.read(tmp_path / "t.vtu").point_data["abnormal_probability"].shape == (n,)
    assert (tmp_path / "t.png").stat().st_size > 10_000


def test_predict_writes_the_tissue_beside_and_a_model_without_a_head_refuses(
    heart_file, tiny_store, tiny_config, tmp_path
):
    from learner.observations import observations_from_store
    from learner.store_view import StoreView

    args = ["predict", str(heart_file), "--sites", "5", "--out", str(tmp_path / "p.npz")]
    result = CliRunner().invoke(app, [*args, "--tissue", str(tmp_path / "t.npz")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "t.npz").exists() and (tmp_path / "p.npz").exists()
    out = tmp_path / "plain"
    Trainer(tiny_config(tiny_store, out, epochs=1), progress=False).fit()
    sites = [int(s) for s in StoreView(tiny_store).sites("lv")[:2]]
    personalize(out / "last.pt", observations_from_store(tiny_store, "lv-healthy", sites, "surface"), out / "h.pt")
    result = CliRunner().invoke(app, ["tissue", str(out / "h.pt"), "--out", str(tmp_path / "x.npz")])
    assert result.exit_code != 0 and "infers no tissue" in result.output

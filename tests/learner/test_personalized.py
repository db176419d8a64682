"""A personalised heart: recordings without a wave left out, operators kept, a file that loads without a rebuild."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

import learner.graph.hierarchy as hierarchy_module
from learner.observations import Observations, observations_from_file
from learner.personalized import NoWaveWarning, PersonalizedHeart, personalize, predict
from learner.train.trainer import Trainer
from shared.errors import InputError
from shared.sites import SiteLabels


@pytest.fixture(scope="module")
def checkpoint(tiny_store, tiny_config, tmp_path_factory):
    """A metaPNS trained for one epoch on the tiny store, on a working graph of 200 clusters."""
    out = tmp_path_factory.mktemp("run")
    Trainer(tiny_config(tiny_store, out, model={"working_nodes": 200}, epochs=1), progress=False).fit()
    return out / "last.pt"


@pytest.fixture(scope="module")
def recordings(tiny_store):
    """Four recordings of the tiny store's healthy LV, every node observed; the last shows no wave."""
    from learner.observations import observations_from_store
    from learner.store_view import StoreView

    sites = [int(s) for s in StoreView(tiny_store).sites("lv")[:4]]
    full = observations_from_store(tiny_store, "lv-healthy", sites, "surface")
    obs = full.obs.copy()
    obs[3] = 0.0  # the patch alone, as a stimulus in a scar core
    return Observations(full.mesh, full.sites, obs, full.observed, full.times, "lv-healthy")


def test_recordings_without_a_wave_are_left_out_and_named(checkpoint, recordings):
    with pytest.warns(NoWaveWarning, match=f"{recordings.sites[3]} \\(0.0%\\)"):
        heart = personalize(checkpoint, recordings)
    assert heart.dropped == [(int(recordings.sites[3]), 0.0)]
    quiet = Observations(recordings.mesh, recordings.sites, 0 * recordings.obs, recordings.observed, recordings.times)
    with pytest.raises(InputError, match="none of the 4 recordings shows a propagating wave"):
        personalize(checkpoint, quiet)


def test_a_heart_in_memory_and_its_file_predict_the_same(checkpoint, recordings, tmp_path, monkeypatch):
    with pytest.warns(NoWaveWarning):
        heart = personalize(checkpoint, recordings, tmp_path / "heart.pt")
    assert heart.hierarchy.working is not None and heart.hierarchy.sizes[0] <= 200
    sites = [5, 77, 300]
    first = heart.predict(sites)
    assert first.u.shape == (3, recordings.obs.shape[1], recordings.mesh.n_nodes)
    torch.testing.assert_close(torch.as_tensor(heart.predict(sites).u), torch.as_tensor(first.u))
    heard = []  # what drawing c will cost, said before the draws
    drawn = heart.predict(sites, 3, on_estimate=lambda seconds, mb: heard.append((seconds, mb)))
    assert len(heard) == 1 and heard[0][0] > 0 and heard[0][1] == pytest.approx(3 * first.u.size * 8 / 2**20)
    assert drawn.spread.shape == first.u.shape and drawn.activation_spread.shape == first.u[:, 0].shape

    def no_rebuild(*args, **kwargs):
        raise AssertionError("the graph hierarchy was rebuilt: the file holds it")

    monkeypatch.setattr(hierarchy_module, "build_hierarchy", no_rebuild)
    loaded = PersonalizedHeart.load(tmp_path / "heart.pt")
    assert loaded.dropped == heart.dropped and loaded.subject == "lv-healthy"
    np.testing.assert_allclose(loaded.predict(sites).u, first.u, atol=1e-6)
    np.testing.assert_allclose(predict(tmp_path / "heart.pt", sites).u, first.u, atol=1e-6)
    np.testing.assert_array_equal(first.started_wave, first.activated > 0.2)
    _edited_copies_are_refused_in_one_line(tmp_path / "heart.pt", tmp_path)


def _edited_copies_are_refused_in_one_line(path, folder):
    """Each edit of a personalised file (points moved, times stretched, NaN, a reshaped tensor, the
    digests dropped) is refused on load naming it."""
    saved = torch.load(path, weights_only=True)
    edits = {
        "points": lambda p: p["points"].add_(1000.0),
        "times": lambda p: p["times"].mul_(12.9),
        "c_mu": lambda p: p["c_mu"].fill_(float("nan")),
        "model/": lambda p: p["model"].update({k: v.reshape(-1) for k, v in list(p["model"].items())[:1]}),
        "no digests": lambda p: p.pop("digests"),
    }
    for name, edit in edits.items():
        copy = {
            k: (dict(v) if isinstance(v, dict) else v.clone() if torch.is_tensor(v) else v) for k, v in saved.items()
        }
        edit(copy)
        torch.save(copy, folder / "edited.pt")
        with pytest.raises(InputError) as err:
            PersonalizedHeart.load(folder / "edited.pt")
        message = str(err.value)
        assert "\n" not in message and (name in message if name != "no digests" else "no digests" in message), message
        assert name == "no digests" or "differ from the digests the file was written with" in message


def test_sites_by_position_resolve_on_the_hearts_mesh_and_regions_need_labels(checkpoint, recordings):
    with pytest.warns(NoWaveWarning):
        heart = personalize(checkpoint, recordings)
    node = 123
    assert heart.sites([4], xyz=recordings.mesh.points[[node]] + 0.5).tolist() == [4, node]
    with pytest.raises(InputError, match="region labels"):
        heart.sites(regions=["aha-1"])
    with pytest.raises(InputError, match=rf"sites node {node} and point \(.*\) are one stimulation node \({node}\)"):
        heart.sites([node], xyz=recordings.mesh.points[[node]] + 0.5)


def test_observation_files_take_points_for_sites_and_carry_region_labels(tmp_path, recordings):
    from simgen.meshes import get_mesh
    from simgen.meshes.regions import site_labels

    mesh = get_mesh("lv", 500)
    labels = site_labels(mesh)
    k, t = 2, 6
    arrays = dict(
        points=mesh.points,
        cells=mesh.cells,
        obs=np.full((k, t, mesh.n_nodes), 0.5, np.float32),
        observed=np.ones(mesh.n_nodes, bool),
        times=0.6 * np.arange(1, t + 1),
        site_xyz=mesh.points[[10, 200]] + 1.0,
        **labels.arrays(),
    )
    np.savez(tmp_path / "xyz.npz", **arrays)
    obs = observations_from_file(tmp_path / "xyz.npz")
    assert obs.sites.tolist() == [10, 200]
    assert isinstance(obs.labels, SiteLabels) and (obs.labels.segment == labels.segment).all()
    np.savez(tmp_path / "both.npz", **arrays, sites=np.array([10, 201]))
    with pytest.raises(InputError, match="sites and site_xyz name different nodes"):
        observations_from_file(tmp_path / "both.npz")
    far = {**arrays, "site_xyz": np.array([[0.0, 0.0, 500.0], [0.0, 0.0, 0.0]])}
    np.savez(tmp_path / "far.npz", **far)
    with pytest.raises(InputError, match="no node within 5 mm"):
        observations_from_file(tmp_path / "far.npz")
    assert observations_from_file(tmp_path / "far.npz", tolerance=1000.0).sites[0] >= 0
    twice = {**{k: v for k, v in arrays.items() if k != "site_xyz"}, "sites": np.array([10, 10])}
    np.savez(tmp_path / "twice.npz", **twice)
    with pytest.raises(InputError, match="recorded more than once"):
        observations_from_file(tmp_path / "twice.npz")


def test_a_triangle_surface_of_any_size_is_personalised_and_predicted_on_its_nodes(checkpoint, tiny_store):
    from simgen.meshes import get_mesh
    from simgen.solver.simulate import Simulator, SolverConfig

    surface = get_mesh("lv", 1500, "triangle")
    config = SolverConfig(frames=12, output_interval=2.0)
    truth = Simulator(surface, config=config).run(np.array([0, 400, 900]), threads=2)
    observed = np.zeros(surface.n_nodes, bool)
    observed[::3] = True
    context = Observations(surface, truth.sites[:2], truth.u[:2] * observed, observed, truth.times)
    heart = personalize(checkpoint, context)
    assert heart.hierarchy.working is not None and heart.hierarchy.mesh_nodes == surface.n_nodes
    assert heart.predict([900]).u.shape == (1, 12, surface.n_nodes)


def test_spreads_accumulated_draw_by_draw_equal_the_stacked_std():
    from learner.metrics import activation_times
    from learner.personalized import _spreads

    rng = np.random.default_rng(0)
    times = 0.6 * np.arange(1, 21)
    onset = rng.uniform(1.0, 14.0, (7, 2, 1, 30))
    onset[:3, 0, 0, :5] = 99.0  # some draws never activate some nodes
    onset[:, 1, 0, 0] = 99.0  # a node no draw activates
    draws = (1.0 / (1.0 + np.exp(-3.0 * (times[None, None, :, None] - onset)))).astype(np.float32)
    spread, act_spread = _spreads(iter(draws), times)
    np.testing.assert_allclose(spread, draws.std(axis=0), atol=1e-6)
    act = np.stack([[activation_times(u, times) for u in draw] for draw in draws])
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        expected = np.nanstd(act, axis=0)
    np.testing.assert_allclose(act_spread, expected, atol=1e-9)
    assert np.isnan(act_spread[1, 0])

"""The observation model: masks, noise, and the same observation in simulation data, training and the benchmark."""

from __future__ import annotations

import numpy as np
import pytest

from shared.errors import InputError, SchemaError
from shared.observation import OBSERVATION_SETS, Observation, gaussian_noise, node_mask, observe
from shared.reader import read_index_set

NOISE = 0.02


def test_observe_is_field_plus_noise_masked() -> None:
    u = np.random.default_rng(0).random((2, 3, 10)).astype(np.float32)
    mask = node_mask(10, [1, 4, 7])
    y = observe(u, mask, NOISE, np.random.default_rng(5))
    e = np.random.default_rng(5).standard_normal(u.shape, dtype=np.float32)
    np.testing.assert_array_equal(y[..., mask], (u + np.float32(NOISE) * e)[..., mask])
    assert y.dtype == np.float32 and not y[..., ~mask].any()
    np.testing.assert_array_equal(observe(u, mask), np.where(mask, u, 0))


def test_noise_dtypes_and_errors() -> None:
    assert gaussian_noise((4,), 1.0, np.random.default_rng(0)).dtype == np.float32
    np.testing.assert_array_equal(
        gaussian_noise((4,), NOISE, np.random.default_rng(0), np.float64),
        np.random.default_rng(0).normal(0, NOISE, 4),
    )
    with pytest.raises(InputError, match="needs an rng"):
        observe(np.zeros(3), np.ones(3, bool), NOISE)
    with pytest.raises(InputError, match="empty 'electrodes' node set"):
        node_mask(3, [], "electrodes", "lv")
    with pytest.raises(SchemaError, match="outside"):
        node_mask(3, [3])
    with pytest.raises(InputError, match="noise_std"):
        Observation("surface", -1.0)
    with pytest.raises(InputError, match="choose one of"):
        Observation("sock")
    assert "electrodes" in OBSERVATION_SETS and "all" in OBSERVATION_SETS


def test_training_episode_and_benchmark_fold_observe_alike(tiny_store) -> None:
    """One simulation, one generator state: a training episode and a benchmark fold see the same values."""
    from learner.benchmark import observe_fold
    from learner.data.episodes import EpisodeDataset, EpisodeSpec

    subject = "lv-healthy"
    spec = EpisodeSpec(context=(3, 3), targets=1, observe="electrodes", noise_std=NOISE)
    dataset = EpisodeDataset(tiny_store, [subject], spec, seed=4)
    episode = dataset.episode(subject)
    (context, (left,)), rng = dataset._draw(0, 0)  # the sites and the generator the episode's noise comes from
    fold, recording = observe_fold(str(tiny_store), subject, context, int(left), Observation("electrodes", NOISE), rng)
    np.testing.assert_array_equal(fold.context_rows, episode.context_rows)
    np.testing.assert_array_equal(fold.observed, episode.observed)
    np.testing.assert_array_equal(fold.context_obs, episode.context_obs)
    assert not np.array_equal(fold.context_obs, fold.context_u * fold.observed)  # noisy
    assert recording.dtype == np.float64 and recording.shape == fold.target_u[0].shape


def test_simgen_sock_observes_as_the_store_electrodes(tiny_store) -> None:
    """simgen's sock is the store's ``electrodes`` node set, observed with the same noise for the same seed."""
    from learner.data.episodes import load_episode
    from learner.store_view import StoreView
    from simgen.observe import make_observation

    view = StoreView(tiny_store)
    subject = "lv-healthy"
    mesh_id = view.mesh_of[subject]
    electrodes = read_index_set(tiny_store, mesh_id, "electrodes")
    sock = make_observation("electrodes", n_electrodes=len(electrodes), noise_std=NOISE, seed=11)
    mesh = view.mesh(mesh_id)
    np.testing.assert_array_equal(sock.indices(mesh), electrodes)
    ep = load_episode(tiny_store, subject, [0, 2], [], "electrodes", NOISE, np.random.default_rng(11))
    np.testing.assert_array_equal(sock.observe(mesh, ep.context_u.numpy()), ep.context_obs.numpy()[..., electrodes])

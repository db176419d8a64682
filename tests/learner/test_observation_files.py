"""Observation files as recordings come: mV or u, any frame times, activation-time maps; each refused clearly."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from learner.activation_maps import ApTemplate
from learner.observations import UnmappedWarning, observations_from_file, resample_frames
from shared.errors import InputError
from simgen.meshes import get_mesh

MODEL_TIMES = 0.6 * np.arange(1, 56)  # 7.74 ms apart
MS = 12.9


@pytest.fixture(scope="module")
def lv():
    return get_mesh("lv", 300)


@pytest.fixture(scope="module")
def recording(lv):
    """Two smooth potential sequences (K, 55, N) in u, with a wave sweeping the mesh."""
    x = lv.points[:, 0]
    arrival = 2.0 + 10.0 * (x - x.min()) / np.ptp(x)
    t = MODEL_TIMES[None, :, None]
    u = 1.0 / (1.0 + np.exp(-3.0 * (t - arrival[None, None, :] - np.array([0.0, 1.5])[:, None, None])))
    return u.astype(np.float32)


def write(path, lv, **arrays):
    np.savez(path, points=lv.points, cells=lv.cells, sites=np.array([0, 5]), **arrays)
    return path


def test_millivolts_and_ms_read_as_u_and_model_time(tmp_path, lv, recording):
    observed = np.ones(lv.n_nodes, bool)
    as_u = observations_from_file(write(tmp_path / "u.npz", lv, obs=recording, observed=observed, times=MODEL_TIMES))
    mv = 100.0 * recording - 80.0
    mv[:, :, 3] = np.nan  # an unrecorded node: ignored
    observed[3] = False
    as_mv = observations_from_file(
        write(tmp_path / "mv.npz", lv, obs_mv=mv, observed=observed, times_ms=MODEL_TIMES * MS)
    )
    np.testing.assert_allclose(as_mv.obs[:, :, observed], as_u.obs[:, :, observed], atol=1e-5)
    assert not as_mv.obs[:, :, 3].any()  # unobserved values are zeroed, NaN included
    np.testing.assert_allclose(as_mv.times, MODEL_TIMES)


def test_other_frame_times_are_resampled_to_the_models(tmp_path, lv, recording):
    coarse = MODEL_TIMES[1::2]  # every 15.48 ms, from 15.48 to 418 ms: within one frame of 7.74 and 425.7
    direct = np.stack(
        [[np.interp(MODEL_TIMES, coarse, recording[k, 1::2, n]) for n in range(lv.n_nodes)] for k in range(2)]
    ).transpose(0, 2, 1)
    np.testing.assert_allclose(resample_frames(recording[:, 1::2], coarse, MODEL_TIMES), direct, atol=1e-6)
    path = write(
        tmp_path / "coarse.npz", lv, obs=recording[:, 1::2], observed=np.ones(lv.n_nodes, bool), times_ms=coarse * MS
    )
    obs = observations_from_file(path).at_frames(MODEL_TIMES, lambda: None)
    assert obs.obs.shape == (2, 55, lv.n_nodes)
    np.testing.assert_allclose(obs.obs, direct, atol=1e-6)
    with pytest.raises(InputError, match=r"do not cover the model's 55 frames at 7.74, 15.48, ..., 425.70 ms"):
        resample_frames(recording[:, :20], MODEL_TIMES[:20], MODEL_TIMES)
    with pytest.raises(InputError, match="increase strictly"):
        resample_frames(recording[:, :3], MODEL_TIMES[[0, 2, 1]], MODEL_TIMES)


def test_activation_maps_read_the_nodes_every_recording_maps(tmp_path, lv):
    act = np.tile(40.0 + 0.1 * np.arange(lv.n_nodes), (2, 1))
    act[0, :10] = np.nan  # mapped in one recording only
    act[:, 10:20] = np.nan  # mapped in neither
    act[1, 30] = np.inf  # mapped, never activated
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        obs = observations_from_file(write(tmp_path / "maps.npz", lv, activation_ms=act))
    assert any(issubclass(w.category, UnmappedWarning) and "10 node(s)" in str(w.message) for w in caught)
    assert obs.observed.sum() == lv.n_nodes - 20 and obs.obs is None
    template = ApTemplate(np.array([-1.0, 0.0, 1.0]), np.array([0.0, 0.5, 1.0]))
    rendered = obs.at_frames(MODEL_TIMES, lambda: template)
    assert rendered.obs.shape == (2, 55, lv.n_nodes) and rendered.activation is None
    a = act[0, 25] / MS
    np.testing.assert_allclose(rendered.obs[0, :, 25], np.interp(MODEL_TIMES - a, [-1, 0, 1], [0, 0.5, 1]), atol=1e-6)
    assert not rendered.obs[1, :, 30].any() and not rendered.obs[:, :, 15].any()
    # the model reads each node up to the end of its upstroke (offset 1.0 here), never-activated nodes throughout
    assert obs.recorded is None and rendered.recorded.shape == rendered.obs.shape
    np.testing.assert_array_equal(rendered.recorded[0, :, 25], MODEL_TIMES <= a + 1.0)
    assert rendered.recorded[1, :, 30].all() and not rendered.recorded[:, :, 15].any()


@pytest.mark.parametrize(
    "arrays, message",
    [
        ({"obs": 1, "obs_mv": 1}, "give one of obs_mv and obs (recordings), not both"),
        ({"obs_mv": 1}, "lacks array(s) ['times_ms or times', 'observed']"),
        ({"obs_mv": 1, "times_ms": 1, "times": 1, "observed": 1}, "give one of times_ms and times"),
        ({"obs_mv": "u", "times_ms": 1, "observed": 1}, "obs_mv ranges from"),
        ({"activation_ms": "negative"}, "activation_ms has 1 negative time(s)"),
        ({"activation_ms": "gap", "observed": 1}, "activation_ms is NaN at nodes that observed marks as recorded"),
        ({}, "lacks array(s) ['obs_mv or obs or activation_ms or ecg_mv or ecg', 'times_ms or times', 'observed']"),
    ],
)
def test_unreadable_recordings_are_refused_by_name(tmp_path, lv, recording, arrays, message):
    n = lv.n_nodes
    values = {
        "obs": recording,
        "obs_mv": recording if arrays.get("obs_mv") == "u" else 100 * recording - 80,
        "times_ms": MODEL_TIMES * MS,
        "times": MODEL_TIMES,
        "observed": np.ones(n, bool),
        "activation_ms": np.full((2, n), 40.0),
    }
    if arrays.get("activation_ms") == "negative":
        values["activation_ms"][1, 7] = -3.0
    if arrays.get("activation_ms") == "gap":
        values["activation_ms"][0, 7] = np.nan
    path = write(tmp_path / "bad.npz", lv, **{name: values[name] for name in arrays})
    with pytest.raises(InputError) as err:
        observations_from_file(path)
    assert message in str(err.value)

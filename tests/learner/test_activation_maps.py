"""Activation-time maps as recordings: the template, its rendering, and episodes recorded as maps."""

from __future__ import annotations

import numpy as np
import pytest

from learner.activation_maps import ApTemplate, template_from_sequences
from learner.data.episodes import EpisodeDataset, EpisodeSpec, recorded_map
from shared.capture import ACTION_POTENTIAL_PEAK, mapped_activation
from shared.errors import InputError

TIMES = 0.6 * np.arange(1, 56)


def waveform(t: np.ndarray) -> np.ndarray:
    """A smooth action potential crossing 0.5 at t = 0: upstroke, plateau and repolarisation."""
    return 1.0 / (1.0 + np.exp(-4.0 * t)) * (1.0 - 1.0 / (1.0 + np.exp(-(t - 20.0))))


def test_rendering_is_the_template_shifted_to_each_activation_time():
    template = ApTemplate(np.linspace(-10, 30, 401), waveform(np.linspace(-10, 30, 401)))
    activation = np.array([[2.0, 7.3, np.inf, np.nan]])
    u = template.render(activation, TIMES)
    assert u.shape == (1, 55, 4) and u.dtype == np.float32
    for node in (0, 1):
        expected = np.interp(TIMES - activation[0, node], template.offsets, template.u)
        np.testing.assert_allclose(u[0, :, node], expected, atol=1e-6)
    assert np.allclose(u[0, :, 2], template.u[0]) and np.all(u[0, :, 3] == 0)  # never activated: rest; unmapped: 0


def test_a_map_fixes_each_nodes_frames_up_to_the_end_of_its_upstroke():
    template = ApTemplate(np.array([-1.0, 0.0, 1.0, 2.0, 3.0]), np.array([0.0, 0.5, 0.96, 1.0, 0.8]))
    assert template.upstroke_end == 1.0  # the first offset >= 0 at 95% of the peak
    fixed = template.fixed(np.array([[0.5, np.inf, np.nan]]), np.array([0.0, 1.0, 1.5, 2.0, 3.0]))
    assert fixed.shape == (1, 5, 3) and fixed.dtype == bool
    np.testing.assert_array_equal(fixed[0, :, 0], [True, True, True, False, False])  # up to 0.5 + 1.0
    assert fixed[0, :, 1].all() and not fixed[0, :, 2].any()  # never activated: rest throughout; unmapped: none


def test_the_template_of_shifted_waveforms_is_the_waveform():
    rng = np.random.default_rng(0)
    shifts = rng.uniform(1.0, 10.0, (3, 40))
    u = waveform(TIMES[None, :, None] - shifts[:, None, :])  # (3, 55, 40)
    template = template_from_sequences(u, TIMES)
    inside = (template.offsets > -0.5) & (template.offsets < 21.0)  # offsets every series reaches
    # activation times found between frames 0.6 apart blur the upstroke a little, nothing else
    np.testing.assert_allclose(template.u[inside], waveform(template.offsets[inside]), atol=0.05)
    after = (template.offsets > 2.0) & (template.offsets < 21.0)
    np.testing.assert_allclose(template.u[after], waveform(template.offsets[after]), atol=0.01)
    assert template.u[0] == 0.0  # before any recorded frame: rest
    assert ApTemplate.from_dict(template.to_dict()).u == pytest.approx(template.u, abs=1e-6)


@pytest.mark.parametrize(
    "data, word",
    [
        ({"offsets": [0, 1]}, "offsets"),
        ({"offsets": [0, 1], "u": [0.0]}, "same length"),
        ({"offsets": [1, 0], "u": [0.0, 1.0]}, "increase"),
        ({"offsets": [0, 1], "u": [0.0, float("nan")]}, "finite"),
    ],
)
def test_a_bad_template_is_refused(data, word):
    with pytest.raises(InputError, match=word):
        ApTemplate.from_dict(data)


def test_a_node_that_touches_the_threshold_without_firing_is_mapped_as_never():
    activation = np.array([[1.0, 2.0, np.nan]])
    peak = np.array([[1.0, ACTION_POTENTIAL_PEAK - 0.2, 0.1]])
    np.testing.assert_array_equal(mapped_activation(activation, peak), [[1.0, np.inf, np.inf]])


def test_an_episode_recorded_as_maps_is_its_maps_rendered(tiny_store):
    template = ApTemplate(np.linspace(-40, 40, 801), waveform(np.linspace(-40, 40, 801)))
    plain = EpisodeSpec(context=(2, 2), targets=1, observe="surface")
    maps = EpisodeSpec(context=(2, 2), targets=1, observe="surface", activation_maps=1.0, activation_noise_ms=0.0)
    subjects = ["lv-healthy"]
    ep = EpisodeDataset(tiny_store, subjects, maps, seed=0, template=template).episode(0)
    same = EpisodeDataset(tiny_store, subjects, plain, seed=0).episode(0)
    assert np.array_equal(ep.context_sites, same.context_sites)  # the maps change the recordings, not the sites
    u, observed = ep.context_u.numpy(), ep.observed.numpy()
    times = ep.times.numpy().astype(np.float64)
    expected, fixed = recorded_map(u, times, observed, template, 0.0, np.random.default_rng(0))
    np.testing.assert_allclose(ep.context_obs.numpy(), expected, atol=1e-6)
    assert not ep.context_obs.numpy()[:, :, ~observed].any()
    # the encoder reads the frames the maps fix: observed nodes up to their upstrokes
    np.testing.assert_array_equal(ep.context_recorded.numpy(), fixed)
    assert not fixed[:, :, ~observed].any() and fixed[:, 0, observed].all() and not fixed[:, -1, observed].all()
    assert same.context_recorded is None
    with pytest.raises(InputError, match="activation_maps"):
        EpisodeSpec(activation_maps=1.5)
    with pytest.raises(InputError, match="activation_noise_ms"):
        EpisodeSpec(activation_noise_ms=-1.0)

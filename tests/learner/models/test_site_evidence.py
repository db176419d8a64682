"""SiteEvidence: the context's peak at a stimulation node, hand-computed, and the gate that reads it."""

from __future__ import annotations

import pytest
import torch

from learner.config import ModelConfig
from learner.data.episodes import load_episode
from learner.models.site_evidence import SiteEvidence
from learner.models.surrogate import MetaPNS
from learner.store_view import StoreView
from shared.errors import ConfigError

CONFIG = ModelConfig(
    channels=(4, 8),
    hidden=16,
    latent=8,
    levels=3,
    coarsest=10,
    coarse_blocks=1,
    capture_gate=True,
    capture_evidence=True,
)


def _evidence() -> SiteEvidence:
    """Two context sequences of 3 frames on 4 nodes, stimulated at nodes 0 and 1; node 3 unobserved."""
    obs = torch.tensor(
        [
            [[1.0, 0.1, 0.0, 0.0], [0.2, 0.6, 0.3, 0.0], [0.0, 0.2, 0.4, 0.0]],  # site 0: peaks 1.0 0.6 0.4 0
            [[0.0, 1.0, 0.0, 0.0], [0.1, 0.5, 0.9, 0.0], [0.05, 0.0, 0.2, 0.0]],  # site 1: peaks 0.1 1.0 0.9 0
        ]
    )
    observed = torch.tensor([True, True, True, False])
    return SiteEvidence.from_context(obs, observed, torch.tensor([0, 1]))


def test_peaks_are_per_sequence_maxima_over_frames_and_zero_where_unobserved():
    ev = _evidence()
    torch.testing.assert_close(ev.peaks, torch.tensor([[1.0, 0.6, 0.4, 0.0], [0.1, 1.0, 0.9, 0.0]]))


def test_a_site_is_judged_by_the_sequences_stimulated_elsewhere():
    """Node 0: only sequence 1 (peak 0.1); node 1: only sequence 0 (0.6); node 2: both (0.9); node 3: unobserved."""
    features = _evidence().at(torch.tensor([0, 1, 2, 3]))
    expected = torch.tensor([[0.1, 1.0], [0.6, 1.0], [0.9, 1.0], [0.0, 0.0]])
    torch.testing.assert_close(features, expected)


def test_a_site_whose_only_sequence_is_its_own_has_no_evidence():
    ev = _evidence()
    alone = SiteEvidence(ev.peaks[:1], ev.sites[:1], ev.observed)
    torch.testing.assert_close(alone.at(torch.tensor([0, 2])), torch.tensor([[0.0, 0.0], [0.4, 1.0]]))


def test_mismatched_context_is_refused():
    with pytest.raises(ValueError, match="does not match"):
        SiteEvidence.from_context(torch.zeros(2, 3, 4), torch.ones(4, dtype=torch.bool), torch.tensor([0]))


def test_evidence_needs_the_gate():
    with pytest.raises(ConfigError, match="capture_gate"):
        ModelConfig(capture_evidence=True)


def test_the_gate_reads_the_evidence_at_the_site_only(tiny_store):
    """g moves with the peak at the site node, not with peaks elsewhere, and a model that reads it requires it."""
    view = StoreView(tiny_store)
    hier = view.hierarchy("lv", CONFIG.levels, CONFIG.coarsest)
    ep = load_episode(tiny_store, "lv-scar-apex", [0, 5], [1, 2, 3], "surface")
    torch.manual_seed(0)
    model = MetaPNS(CONFIG, view.frames)
    with torch.no_grad():
        model.capture[-1].weight.normal_(0.0, 0.5)
        c = model.embed(ep.context_obs, ep.observed, hier).mu
        ev = SiteEvidence.of(ep)
        sites = ep.target_sites
        gate = model.capture_probability(sites, hier, c, ev)
        elsewhere = torch.ones(ev.peaks.shape[1], dtype=torch.bool)
        elsewhere[sites] = False
        far = SiteEvidence(ev.peaks + 0.7 * elsewhere, ev.sites, ev.observed)
        torch.testing.assert_close(model.capture_probability(sites, hier, c, far), gate)
        near = SiteEvidence(ev.peaks + 0.7 * ~elsewhere, ev.sites, ev.observed)
        assert bool(((model.capture_probability(sites, hier, c, near) - gate).abs() > 1e-4).all())
        with pytest.raises(ValueError, match="pass evidence"):
            model.generate(sites, hier, c)


def test_a_personalised_model_keeps_its_evidence(tiny_store, tiny_config, tmp_path):
    """`learner personalize` stores the context's evidence: `predict` then equals generate with the live context."""
    from learner.observations import observations_from_store
    from learner.personalized import personalize, predict
    from learner.train.trainer import Trainer, load_model

    model_keys = {"capture_gate": True, "capture_evidence": True}
    Trainer(tiny_config(tiny_store, tmp_path / "run", model=model_keys, epochs=1), progress=False).fit()
    checkpoint = tmp_path / "run" / "last.pt"
    sites = StoreView(tiny_store).sites("lv")
    observations = observations_from_store(tiny_store, "lv-scar-apex", [int(sites[0]), int(sites[3])], "surface")
    personalize(checkpoint, observations, tmp_path / "p.pt")
    targets = [int(sites[3]), int(sites[5])]  # a context site, scored without its own sequence, and a new one
    predicted = predict(tmp_path / "p.pt", targets).u
    model, config, _ = load_model(checkpoint)
    hier = StoreView(tiny_store).hierarchy("lv", config.model.levels, config.model.coarsest)
    obs, observed = torch.as_tensor(observations.obs), torch.as_tensor(observations.observed)
    with torch.no_grad():
        c = model.embed(obs, observed, hier).mu
        ev = SiteEvidence.from_context(obs, observed, torch.as_tensor(observations.sites))
        expected = model.generate(torch.tensor(targets), hier, c, evidence=ev)
    torch.testing.assert_close(torch.as_tensor(predicted), expected)

"""learner: meta-learned personalised neural surrogates (metaPNS) and the generic PNS.

Trains on episodes read from a simgen dataset store, evaluates, personalises from a few observed
simulations, predicts new stimulation sites, and compares with Bayesian-optimisation baselines
(docs/surrogate.md). The names below are the public API; each loads its module on first use, so
``import learner`` does not import torch::

    import learner

    observations = learner.observations_from_file("recordings.npz")
    heart = learner.personalize("anatomies", observations)  # a shipped model, or a trained best.pt
    prediction = heart.predict([818, 631])  # again and again: the heart keeps its operators
    heart.save("heart.pt")  # learner.predict("heart.pt", [818]) in another process

Training and evaluation are :func:`learner.train.train` and :func:`learner.evaluate.evaluate`
(``learner train``, ``learner evaluate``): their modules have those names, so the top level does not.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from shared.lazy import attach

if TYPE_CHECKING:
    from learner.benchmark import BenchmarkConfig, load_benchmark_config, run_benchmark
    from learner.config import LearnerConfig, load_config
    from learner.data import EpisodeDataset, EpisodeSpec, load_episode
    from learner.evaluate import EvalReport, EvalSetting, EvalSpec, evaluate_methods
    from learner.methods import METHODS, build_methods
    from learner.models import PNS, MetaPNS, build_model
    from learner.observations import Observations, observations_from_file, observations_from_store, read_mesh_file
    from learner.personalized import PersonalizedHeart, Prediction, personalize, predict
    from learner.store_view import StoreView
    from learner.train import Trainer, load_model
    from shared.observation import Observation

__all__ = [
    "LearnerConfig",
    "load_config",
    "StoreView",
    "EpisodeSpec",
    "EpisodeDataset",
    "load_episode",
    "Observation",
    "PNS",
    "MetaPNS",
    "build_model",
    "Trainer",
    "load_model",
    "EvalSpec",
    "EvalSetting",
    "EvalReport",
    "evaluate_methods",
    "METHODS",
    "build_methods",
    "Observations",
    "observations_from_store",
    "observations_from_file",
    "read_mesh_file",
    "PersonalizedHeart",
    "Prediction",
    "personalize",
    "predict",
    "BenchmarkConfig",
    "load_benchmark_config",
    "run_benchmark",
]

#: Public name -> the module that defines it.
_EXPORTS = {
    **dict.fromkeys(["LearnerConfig", "load_config"], "learner.config"),
    "StoreView": "learner.store_view",
    **dict.fromkeys(["EpisodeSpec", "EpisodeDataset", "load_episode"], "learner.data"),
    "Observation": "shared.observation",
    **dict.fromkeys(["PNS", "MetaPNS", "build_model"], "learner.models"),
    **dict.fromkeys(["Trainer", "load_model"], "learner.train"),
    **dict.fromkeys(["EvalSpec", "EvalSetting", "EvalReport", "evaluate_methods"], "learner.evaluate"),
    **dict.fromkeys(["METHODS", "build_methods"], "learner.methods"),
    **dict.fromkeys(
        ["Observations", "observations_from_store", "observations_from_file", "read_mesh_file"], "learner.observations"
    ),
    **dict.fromkeys(["PersonalizedHeart", "Prediction", "personalize", "predict"], "learner.personalized"),
    **dict.fromkeys(["BenchmarkConfig", "load_benchmark_config", "run_benchmark"], "learner.benchmark"),
}


__getattr__, __dir__ = attach(__name__, _EXPORTS)

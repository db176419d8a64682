"""Physics-based personalisation baselines: Bayesian optimisation of simulator tissue parameters.

FS-BO fits one excitability per mesh region; VAE-BO fits the latent code of a
VAE trained on a library of scar maps. Both reach the simulator only through
:mod:`shared.simulator`.
"""

from __future__ import annotations

from learner.baselines.base import (
    FitResult,
    PersonalisationBaseline,
    diffusivity_from_excitability,
    fields_from_excitability,
)
from learner.baselines.bo import BOSettings, BOTrace, bayes_minimise
from learner.baselines.fs_bo import FSBO
from learner.baselines.regions import mesh_regions, region_sizes
from learner.baselines.tissue_library import geodesic_diameter, geodesic_scar, scar_library
from learner.baselines.tissue_vae import TissueVAE, train_tissue_vae
from learner.baselines.vae_bo import VAEBO

__all__ = [
    "PersonalisationBaseline",
    "FitResult",
    "FSBO",
    "VAEBO",
    "BOSettings",
    "BOTrace",
    "bayes_minimise",
    "mesh_regions",
    "region_sizes",
    "scar_library",
    "geodesic_scar",
    "geodesic_diameter",
    "TissueVAE",
    "train_tissue_vae",
    "diffusivity_from_excitability",
    "fields_from_excitability",
]

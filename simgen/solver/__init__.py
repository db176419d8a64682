"""Monodomain solver: P1 FEM operator, cell models, time integrators, batched fused kernels."""

from __future__ import annotations

from simgen.solver.cells import CELL_MODELS, APParams, CellModel, MSParams, cell_model
from simgen.solver.cells.aliev_panfilov import MS_PER_TIME_UNIT, front_speed, reaction, to_millivolts
from simgen.solver.integrators import INTEGRATORS
from simgen.solver.simulate import SimulationResult, Simulator, SolverConfig, healthy_fields, simulate
from simgen.solver.stimulus import check_sites, patch_mask
from simgen.solver.timestep import choose_rkc_step, choose_time_step, largest_eigenvalue, rkc_stages, stability_limit

__all__ = [
    "MS_PER_TIME_UNIT",
    "CELL_MODELS",
    "CellModel",
    "APParams",
    "MSParams",
    "cell_model",
    "front_speed",
    "reaction",
    "to_millivolts",
    "INTEGRATORS",
    "SimulationResult",
    "Simulator",
    "SolverConfig",
    "healthy_fields",
    "simulate",
    "check_sites",
    "patch_mask",
    "choose_time_step",
    "choose_rkc_step",
    "rkc_stages",
    "largest_eigenvalue",
    "stability_limit",
]

"""A tissue in physical terms: conduction velocity (m/s) and action-potential duration (ms), measured on a strip.

As openCARP's ``tuneCV`` does, the speed is measured, not taken from a closed
form: a planar wave crosses a strip of tissue (:func:`simgen.meshes.slab.strip`)
and the speed is the slope of position against activation time over the
strip's middle (:func:`simgen.solver.verification.measured_front_speed`).
The monodomain equation scales with ``sqrt(D)``: a strip meshed at spacing
``h`` with diffusivity ``D`` behaves as one of spacing ``h / sqrt(D)`` with
diffusivity 1, so one strip at ``h / sqrt(D) = 1/8`` (within 0.1 % of the
speed at half that spacing) measures every diffusivity:

    CV(a, D) = sqrt(diffusivity * D) * c1(a),

with ``c1`` the speed at diffusivity 1 of tissue with excitability ``a``. Across
fibres the diffusivity is ``diffusivity * D / anisotropy``. The speed is the
tissue's own, converged in the mesh: a heart meshed at a few mm conducts
somewhat slower (docs/method.md, Convergence). APD90 is the time from the
upstroke (``u`` through the activation threshold) to 90 % repolarisation
(``u`` below 0.1) in the strip's middle, with the tissue's ``apd_scale``.
Both are cached per cell model and excitability.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np

from shared.errors import TissueError
from shared.tissue import TissueSpec
from shared.units import MS_PER_TIME_UNIT
from simgen.meshes.slab import strip
from simgen.solver.cells import CellModel, with_apd_scale
from simgen.solver.simulate import SolverConfig
from simgen.solver.verification import action_potential_duration, measured_front_speed, planar_run

__all__ = ["Physical", "physical", "unit_speed", "apd90", "diffusivity_for_speed"]

#: The strip's length and width and its spacing at diffusivity 1 (mesh units: the strip is scaled by sqrt(D)).
STRIP = (30.0, 1.0, 0.125)


class Physical(NamedTuple):
    """A tissue's conduction velocity ``cv`` (m/s; along fibres where it has an anisotropy), ``cv_across``
    (m/s across fibres; ``None``: isotropic) and ``apd`` (APD90, ms)."""

    cv: float
    cv_across: float | None
    apd: float


@lru_cache(maxsize=256)
def unit_speed(model: CellModel, a: float) -> float:
    """The planar front speed (mesh units per time unit) of tissue with excitability ``a`` at diffusivity 1."""
    mesh = strip(*STRIP)
    try:
        return measured_front_speed(mesh, planar_run(mesh, a, model=model))
    except Exception as exc:  # noqa: BLE001 - any failure of the measurement names the tissue
        raise TissueError(f"tissue with excitability a = {a:g} does not conduct on a strip: {exc}") from None


@lru_cache(maxsize=256)
def apd90(model: CellModel, a: float) -> float:
    """APD90 (ms) of tissue with excitability ``a`` under ``model`` (already scaled by any ``apd_scale``)."""
    mesh = strip(10.0, 0.5, 0.25)
    return MS_PER_TIME_UNIT * action_potential_duration(mesh, x=5.0, model=model, a=a, repolarised=0.1, window=150.0)


def _speed(model: CellModel, solver: SolverConfig, a: float, D: float) -> float:
    """m/s at diffusivity ``solver.diffusivity * D`` (mm^2 per time unit)."""
    return float(np.sqrt(solver.diffusivity * D) * unit_speed(model, a) / MS_PER_TIME_UNIT)


def physical(tissue: TissueSpec, solver: SolverConfig) -> Physical:
    """The healthy tissue of ``tissue`` under ``solver`` in physical terms (see the module docstring)."""
    a, D = tissue.healthy.a, tissue.healthy.D
    anisotropy = tissue.anisotropy or solver.anisotropy
    model = with_apd_scale(solver.model, tissue.apd_scale)
    across = None if anisotropy is None else _speed(model, solver, a, D / anisotropy)
    return Physical(_speed(model, solver, a, D), across, apd90(model, a))


def diffusivity_for_speed(cv: float, a: float, solver: SolverConfig, apd_scale: float | None = None) -> float:
    """The diffusivity scale ``D`` at which tissue with excitability ``a`` (and ``apd_scale``) conducts at
    ``cv`` m/s (along fibres) under ``solver``."""
    model = with_apd_scale(solver.model, apd_scale)
    return float((cv * MS_PER_TIME_UNIT / unit_speed(model, a)) ** 2 / solver.diffusivity)

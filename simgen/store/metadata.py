"""Self-describing attributes of a store: provenance, the simulation model, a subject's solver settings.

They are written once, with the layout they describe (:func:`simgen.store.layout.create_layout`,
:func:`simgen.store.edit.add_subject`), and never rewritten by a resumed build, so
a resumed store stays byte-identical to an uninterrupted one. Two separate
builds differ in their creation date unless ``SOURCE_DATE_EPOCH`` fixes it
(the reproducible-builds convention).
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
from datetime import UTC, datetime
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from shared.errors import ConfigError
from shared.mesh import Mesh
from shared.reader import read_integrator, subject_attrs
from shared.units import MS_PER_TIME_UNIT, TIME_UNITS
from simgen.solver.cells import with_apd_scale
from simgen.solver.integrators import AUTO, INTEGRATORS
from simgen.solver.simulate import SolverConfig
from simgen.store.manifest import SubjectSetup
from simgen.tissue.fields import SCAR_BORDERS

__all__ = [
    "PACKAGE",
    "provenance",
    "simulation_attrs",
    "solver_attrs",
    "recorded_solver",
    "recorded_scar_border",
]

#: The stimulus of subjects whose ``solver`` attribute names no ``stimulus_region`` (stores built before it
#: existed): edge-path patches of this many mean edge lengths where no radius is recorded either.
LEGACY_REGION, LEGACY_EDGES = "geodesic", 1.5
#: The scar border rule of stores whose ``simulation`` attribute names none (built before it existed).
LEGACY_SCAR_BORDER = "nodes"

#: The distribution that writes stores.
PACKAGE = "metapns"


def provenance() -> dict:
    """Package, version, git commit (``None`` outside a checkout) and creation date (UTC, ISO 8601)."""
    return {"software": PACKAGE, "version": _version(), "git_commit": _git_commit(), "created": _created()}


def _version() -> str | None:
    try:
        return version(PACKAGE)
    except PackageNotFoundError:
        return None


def _git_commit() -> str | None:
    """HEAD of the git checkout holding this package, or ``None`` (no git, not a checkout)."""
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=Path(__file__).parent, capture_output=True, text=True, timeout=10
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def _created() -> str:
    """Now, or ``SOURCE_DATE_EPOCH`` (seconds since 1970) when set, as ``YYYY-MM-DDTHH:MM:SS+00:00``."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    if epoch is None:
        when = datetime.now(UTC)
    elif epoch.isdigit():
        when = datetime.fromtimestamp(int(epoch), UTC)
    else:
        raise ConfigError(f"SOURCE_DATE_EPOCH must be a whole number of seconds since 1970, got {epoch!r}")
    return when.isoformat(timespec="seconds")


def simulation_attrs(solver: SolverConfig) -> dict:
    """Root attribute ``simulation``: the model, its constants and the settings every subject shares
    (``anisotropy``, ``D_l / D_t`` along the meshes' fibres, only where set: stores without it are isotropic)."""
    anisotropy = {} if solver.anisotropy is None else {"anisotropy": solver.anisotropy}
    return {
        "model": f"{solver.model.title}, monodomain, P1 finite elements, "
        + INTEGRATORS[solver.integrator or AUTO].title,
        "equations": list(solver.model.equations),
        "constants": {k: v for k, v in dataclasses.asdict(solver.model).items() if v is not None},
        "diffusivity": solver.diffusivity,
        **anisotropy,
        "stimulus_radius": solver.stimulus_radius,
        "stimulus_duration": solver.stimulus_duration,
        "activation_threshold": solver.activation_threshold,
        "scar_border": SCAR_BORDERS[0],
        "output_interval": solver.output_interval,
        "frames": solver.frames,
        "units": {
            "length": "mm",
            "time": TIME_UNITS,
            "ms_per_time_unit": MS_PER_TIME_UNIT,
            "potential": "u dimensionless, V = 100 u - 80 mV",
            "diffusivity": f"mm2 / ({TIME_UNITS})",
        },
    }


def solver_attrs(setup: SubjectSetup, solver: SolverConfig, apd_scale: float | None = None) -> dict:
    """Subject attribute ``solver``: integrator, time step and stimulus as the solver resolved them on its mesh,
    the subject's ``anisotropy`` where it conducts along fibres and its tissue's ``apd_scale`` where it sets one."""
    anisotropy = {} if solver.anisotropy is None else {"anisotropy": solver.anisotropy}
    apd = {} if apd_scale is None else {"apd_scale": apd_scale}
    return {
        **anisotropy,
        **apd,
        "integrator": setup.integrator,
        "dt": setup.dt,
        "steps_per_frame": setup.steps_per_frame,
        "stimulus_radius": setup.stimulus_radius,
        "stimulus_region": solver.region,
        "stimulus_duration": solver.stimulus_duration,
    }


def recorded_solver(store: str, subject_id: str, solver: SolverConfig, mesh: Mesh) -> SolverConfig:
    """``solver`` as it ran on the subject (``mesh`` its mesh): its recorded integrator, stimulus,
    anisotropy (none recorded: isotropic) and action-potential scale (none recorded: the model's own).

    A resumed build, a repair and ``verify`` simulate with these, so a store
    keeps its results whatever the defaults of the code that resumes it.
    Subjects recorded before a setting existed ran its legacy value: forward
    Euler (:func:`~shared.reader.read_integrator`) and edge-path patches of
    the spec's radius, or of :data:`LEGACY_EDGES` mean edge lengths.
    """
    record = subject_attrs(store, subject_id).get("solver") or {}
    radius = record.get("stimulus_radius", solver.stimulus_radius)
    return dataclasses.replace(
        solver,
        model=with_apd_scale(solver.model, record.get("apd_scale")),
        anisotropy=record.get("anisotropy"),
        integrator=read_integrator(store, subject_id),
        stimulus_radius=LEGACY_EDGES * mesh.mean_edge_length() if radius is None else radius,
        stimulus_region=record.get("stimulus_region", LEGACY_REGION),
    )


def recorded_scar_border(attrs: dict) -> str:
    """Where a store's border zones are measured from (:data:`~simgen.tissue.fields.SCAR_BORDERS`), from its
    root attributes ``attrs``: subjects added to it or repaired get the fields of the rule its others have."""
    return (attrs.get("simulation") or {}).get("scar_border", LEGACY_SCAR_BORDER)

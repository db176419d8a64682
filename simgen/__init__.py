"""simgen: Aliev-Panfilov simulation-data service.

Meshes, tissue (scar) settings, the batched solver, observation operators and resumable dataset
builds into one chunked Zarr store. The names below are the public API; each loads its module on
first use, so ``import simgen`` stays cheap (the solver's kernels compile with numba, builds use
Dask and Zarr)::

    import simgen

    mesh = simgen.get_mesh("lv", 2000)
    fields = simgen.tissue_fields(mesh, simgen.default_settings()[5])
    result = simgen.Simulator(mesh, fields).run([0, 500, 1200])

A dataset is built from a spec with :func:`simgen.store.runner.build` (``simgen build`` on the command
line); :mod:`simgen.store` is the package of the store's layout, builds, verification and repair.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from shared.lazy import attach

if TYPE_CHECKING:
    from shared.mesh import Mesh
    from shared.tissue import TissueSpec
    from simgen.demo import run_demo
    from simgen.meshes import biv_ellipsoid, get_mesh, load_mesh, lv_ellipsoid, sample_anatomies, save_mesh
    from simgen.observe import AllSurface, Epicardial, Sock, make_observation
    from simgen.outputs import simulate_files, write_mesh
    from simgen.solver import APParams, SimulationResult, Simulator, SolverConfig, simulate
    from simgen.store import BuildSpec, load_spec, make_plan, spec_from_mapping, spec_hash
    from simgen.store.card import dataset_card
    from simgen.store.edit import add_subject, regenerate
    from simgen.store.export import export_vtk
    from simgen.store.repair import repair_store
    from simgen.store.verify import verify_store
    from simgen.tissue import aha_segments, default_settings, tissue_fields

#: Public name -> the module that defines it.
_EXPORTS = {
    **dict.fromkeys(["Mesh"], "shared.mesh"),
    **dict.fromkeys(["TissueSpec"], "shared.tissue"),
    **dict.fromkeys(
        ["get_mesh", "load_mesh", "save_mesh", "lv_ellipsoid", "biv_ellipsoid", "sample_anatomies"], "simgen.meshes"
    ),
    **dict.fromkeys(["default_settings", "tissue_fields", "aha_segments"], "simgen.tissue"),
    **dict.fromkeys(["Simulator", "SolverConfig", "SimulationResult", "simulate", "APParams"], "simgen.solver"),
    **dict.fromkeys(["Sock", "AllSurface", "Epicardial", "make_observation"], "simgen.observe"),
    **dict.fromkeys(["BuildSpec", "load_spec", "spec_from_mapping", "spec_hash", "make_plan"], "simgen.store"),
    "verify_store": "simgen.store.verify",
    "repair_store": "simgen.store.repair",
    "export_vtk": "simgen.store.export",
    "add_subject": "simgen.store.edit",
    "regenerate": "simgen.store.edit",
    "dataset_card": "simgen.store.card",
    "run_demo": "simgen.demo",
    **dict.fromkeys(["simulate_files", "write_mesh"], "simgen.outputs"),
}

__all__ = [
    "Mesh",
    "TissueSpec",
    "get_mesh",
    "load_mesh",
    "save_mesh",
    "lv_ellipsoid",
    "biv_ellipsoid",
    "sample_anatomies",
    "default_settings",
    "tissue_fields",
    "aha_segments",
    "Simulator",
    "SolverConfig",
    "SimulationResult",
    "simulate",
    "APParams",
    "Sock",
    "AllSurface",
    "Epicardial",
    "make_observation",
    "BuildSpec",
    "load_spec",
    "spec_from_mapping",
    "spec_hash",
    "make_plan",
    "verify_store",
    "repair_store",
    "export_vtk",
    "add_subject",
    "regenerate",
    "dataset_card",
    "run_demo",
    "simulate_files",
    "write_mesh",
]


__getattr__, __dir__ = attach(__name__, _EXPORTS)

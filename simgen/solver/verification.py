"""Measurements with known answers: planar front speed and action-potential duration.

Used by the verification tests and by ``bench/conduction.py``; both excite
the ``x <= 1`` end of a strip or slab (mesh units, D = 1 unless given).
"""

from __future__ import annotations

import numpy as np

from shared.errors import InputError
from shared.mesh import Mesh
from shared.tissue import TissueFields
from simgen.solver.cells import APParams, CellModel
from simgen.solver.simulate import SimulationResult, Simulator, SolverConfig

__all__ = ["planar_run", "measured_front_speed", "speed_error", "action_potential_duration"]


def planar_run(mesh: Mesh, a: float, diffusivity: float = 1.0, **config) -> SimulationResult:
    """Excite the ``x <= 1`` end with uniform excitability ``a``; run until the front can cross
    (``config``: :class:`SolverConfig` settings, ``model`` the cell model)."""
    n = mesh.n_nodes
    tissue = TissueFields(np.full(n, a), np.ones(n), np.zeros(n, np.int8))
    length = float(np.ptp(mesh.points[:, 0]))
    model = config.get("model", APParams())
    speed = max(model.front_speed(diffusivity, a), 0.2 * model.front_speed(diffusivity, 0.0))  # slow fronts too
    frames = int(length / speed) + 5
    cfg = SolverConfig(**{"diffusivity": diffusivity, "output_interval": 1.0, "frames": frames, **config})
    return Simulator(mesh, tissue, cfg).run_patches((mesh.points[:, 0] <= 1.0 + 1e-9)[:, None])


def measured_front_speed(mesh: Mesh, result: SimulationResult) -> float:
    """Slope of x against activation time over the middle (30 - 80 %) of the domain."""
    x = mesh.points[:, 0]
    sel = (x >= 0.3 * x.max()) & (x <= 0.8 * x.max())
    t = result.activation[0, sel]
    if not np.all(np.isfinite(t)):
        raise InputError("the front did not reach the measurement window (no propagation)")
    return float(np.polyfit(t, x[sel], 1)[0])


def speed_error(mesh: Mesh, a: float, diffusivity: float = 1.0, **config) -> float:
    """Relative error of the measured planar speed against the cell model's closed form
    (:meth:`~simgen.solver.cells.aliev_panfilov.APParams.front_speed`; Aliev-Panfilov: ``sqrt(2kD)(1/2 - a)``)."""
    result = planar_run(mesh, a, diffusivity, **config)
    expected = config.get("model", APParams()).front_speed(diffusivity, a)
    return measured_front_speed(mesh, result) / expected - 1.0


def action_potential_duration(
    mesh: Mesh,
    x: float,
    model: CellModel | None = None,
    level: float = 0.5,
    a: float = 0.15,
    repolarised: float | None = None,
    window: float = 50.0,
) -> float:
    """Time (time units) from ``u`` rising through ``level`` to its falling through ``repolarised`` (unset:
    ``level``, APD50; 0.1: APD90) at the node nearest ``(x, 0)`` after a planar stimulus of tissue with
    excitability ``a``, within ``window`` time units."""
    n = mesh.n_nodes
    tissue = TissueFields(np.full(n, a), np.ones(n), np.zeros(n, np.int8))
    interval = 0.05
    frames = int(np.ceil(window / interval))
    cfg = SolverConfig(diffusivity=1.0, output_interval=interval, frames=frames, model=model or APParams())
    result = Simulator(mesh, tissue, cfg).run_patches((mesh.points[:, 0] <= 1.0)[:, None])
    node = int(np.argmin(np.hypot(mesh.points[:, 0] - x, mesh.points[:, 1])))
    u, t = result.u[0, :, node], result.times
    if not (u >= level).any():
        raise InputError(f"the tissue did not excite (a = {a:g}): no action potential")
    up = int(np.argmax(u >= level))
    down = up + int(np.argmax(u[up:] < (level if repolarised is None else repolarised)))
    if down <= up:
        raise InputError("no repolarisation within the simulated window")
    return float(t[down] - t[up])

"""Measurements with known answers: planar front speed and action-potential duration.

Used by the verification tests and by ``bench/conduction.py``; both excite
the ``x <= 1`` end of a strip or slab (mesh units, D = 1 unless given).
"""

from __future__ import annotations

import numpy as np

from shared.errors import InputError
from shared.mesh import Mesh
from shared.tissue import TissueFields
from simgen.solver.aliev_panfilov import APParams, front_speed
from simgen.solver.simulate import SimulationResult, Simulator, SolverConfig

__all__ = ["planar_run", "measured_front_speed", "speed_error", "action_potential_duration"]


def planar_run(mesh: Mesh, a: float, diffusivity: float = 1.0, **config) -> SimulationResult:
    """Excite the ``x <= 1`` end with uniform excitability ``a``; run until the front can cross."""
    n = mesh.n_nodes
    tissue = TissueFields(np.full(n, a), np.ones(n), np.zeros(n, np.int8))
    length = float(np.ptp(mesh.points[:, 0]))
    frames = int(length / front_speed(diffusivity, min(a, 0.4))) + 5
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
    """Relative error of the measured planar speed against ``sqrt(2kD)(1/2 - a)``."""
    result = planar_run(mesh, a, diffusivity, **config)
    return measured_front_speed(mesh, result) / front_speed(diffusivity, a) - 1.0


def action_potential_duration(mesh: Mesh, x: float, model: APParams | None = None, level: float = 0.5) -> float:
    """Time ``u`` stays above ``level`` at the node nearest ``(x, 0)`` after a planar stimulus (APD50)."""
    cfg = SolverConfig(diffusivity=1.0, output_interval=0.05, frames=1000, model=model or APParams())
    result = Simulator(mesh, config=cfg).run_patches((mesh.points[:, 0] <= 1.0)[:, None])
    node = int(np.argmin(np.hypot(mesh.points[:, 0] - x, mesh.points[:, 1])))
    u, t = result.u[0, :, node], result.times
    up = int(np.argmax(u >= level))
    down = up + int(np.argmax(u[up:] < level))
    if down <= up:
        raise InputError("no repolarisation within the simulated window")
    return float(t[down] - t[up])

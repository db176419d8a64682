"""Verification against known answers of the Aliev-Panfilov model.

Planar fronts on structured strips/slabs (D = 1, k = 8) must travel at
``sqrt(2kD)(1/2 - a)``, converge with refinement, fail at a = 0.45, and the
action potential must last about 23 time units (APD50) at a = 0.15.
"""

from __future__ import annotations

import numpy as np
import pytest

from shared.mesh import Mesh
from shared.tissue import TissueFields
from simgen.meshes.slab import slab, strip
from simgen.solver.aliev_panfilov import APParams, front_speed
from simgen.solver.simulate import SimulationResult, Simulator, SolverConfig


def planar_run(mesh: Mesh, a: float, length: float, **config) -> SimulationResult:
    """Excite the x <= 1 end of a strip/slab and integrate long enough to cross it."""
    n = mesh.n_nodes
    tissue = TissueFields(np.full(n, a), np.ones(n), np.zeros(n, np.int8))
    frames = int(length / front_speed(1.0, min(a, 0.4))) + 5
    cfg = SolverConfig(**{"diffusivity": 1.0, "output_interval": 1.0, "frames": frames, **config})
    return Simulator(mesh, tissue, cfg).run_patches((mesh.points[:, 0] <= 1.0 + 1e-9)[:, None])


def measured_speed(mesh: Mesh, result: SimulationResult) -> float:
    """Slope of x against activation time over the middle of the domain."""
    x = mesh.points[:, 0]
    sel = (x >= 0.3 * x.max()) & (x <= 0.8 * x.max())
    t = result.activation[0, sel]
    assert np.all(np.isfinite(t)), "front did not reach the measurement window"
    return float(np.polyfit(t, x[sel], 1)[0])


def relative_speed_error(mesh: Mesh, a: float, length: float) -> float:
    return measured_speed(mesh, planar_run(mesh, a, length)) / front_speed(1.0, a) - 1.0


@pytest.mark.parametrize("a", [0.15, 0.3])
def test_strip_front_speed_within_10_percent(a):
    assert abs(relative_speed_error(strip(30.0, 1.0, 0.25), a, 30.0)) < 0.10


@pytest.mark.parametrize("a", [0.15, 0.3])
def test_slab_front_speed_within_10_percent(a):
    assert abs(relative_speed_error(slab(20.0, 1.0, 1.0, 0.5), a, 20.0)) < 0.10


def test_front_speed_converges_with_refinement():
    errors = [abs(relative_speed_error(strip(30.0, 1.0, h), 0.15, 30.0)) for h in (0.5, 0.25, 0.125)]
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 0.01
    # first-order-or-better decay: halving h at least halves the error at the fine end
    assert errors[2] < 0.6 * errors[1]


def test_no_propagation_at_a_045():
    mesh = strip(30.0, 1.0, 0.25)
    result = planar_run(mesh, 0.45, 30.0)
    far = mesh.points[:, 0] > 10.0
    assert np.all(np.isnan(result.activation[0, far]))
    assert result.u[0, -1].max() < 0.5


def action_potential_duration(variant: str) -> float:
    mesh = strip(10.0, 0.5, 0.25)
    cfg = SolverConfig(diffusivity=1.0, output_interval=0.05, frames=1000, model=APParams(variant=variant))
    result = Simulator(mesh, config=cfg).run_patches((mesh.points[:, 0] <= 1.0)[:, None])
    node = int(np.argmin(np.hypot(mesh.points[:, 0] - 5.0, mesh.points[:, 1])))
    u, t = result.u[0, :, node], result.times
    up = int(np.argmax(u >= 0.5))
    down = up + int(np.argmax(u[up:] < 0.5))
    assert down > up, "no repolarisation within the window"
    return float(t[down] - t[up])


def test_apd50_near_23_time_units():
    assert action_potential_duration("standard") == pytest.approx(23.0, rel=0.1)


def test_simple_variant_propagates_and_repolarises_later():
    mesh = strip(30.0, 1.0, 0.25)
    result = planar_run(mesh, 0.15, 30.0, model=APParams(variant="simple"))
    assert measured_speed(mesh, result) == pytest.approx(front_speed(1.0, 0.15), rel=0.1)
    assert result.u[0, -1].max() > 0.5  # constant eps = 0.01 recovers slower than the standard model

"""Verification against known answers of the Aliev-Panfilov model.

Planar fronts on structured strips/slabs (D = 1, k = 8) must travel at
``sqrt(2kD)(1/2 - a)``, converge with refinement, fail at a = 0.45, and the
action potential must last about 23 time units (APD50) at a = 0.15.
"""

from __future__ import annotations

import numpy as np
import pytest

from shared.errors import InputError
from simgen.meshes.slab import slab, strip
from simgen.solver.cells.aliev_panfilov import APParams, front_speed
from simgen.solver.verification import (
    action_potential_duration,
    measured_front_speed,
    planar_run,
    speed_error,
)


@pytest.mark.parametrize("a", [0.15, 0.3])
def test_strip_front_speed_within_10_percent(a):
    assert abs(speed_error(strip(30.0, 1.0, 0.25), a)) < 0.10


@pytest.mark.parametrize("a", [0.15, 0.3])
def test_slab_front_speed_within_10_percent(a):
    assert abs(speed_error(slab(20.0, 1.0, 1.0, 0.5), a)) < 0.10


def test_front_speed_converges_with_refinement():
    errors = [abs(speed_error(strip(30.0, 1.0, h), 0.15, integrator="euler")) for h in (0.5, 0.25, 0.125)]
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 0.01
    assert errors[2] < 0.6 * errors[1]  # halving h at least nearly halves the error


def test_front_speed_scales_with_sqrt_diffusivity():
    """D = 4 on a mesh twice as coarse is the same problem in rescaled units."""
    assert speed_error(strip(60.0, 2.0, 0.5), 0.15, diffusivity=4.0) == pytest.approx(
        speed_error(strip(30.0, 1.0, 0.25), 0.15), abs=2e-3
    )


def test_no_propagation_at_a_045():
    mesh = strip(30.0, 1.0, 0.25)
    result = planar_run(mesh, 0.45)
    assert np.all(np.isnan(result.activation[0, mesh.points[:, 0] > 10.0]))
    assert result.u[0, -1].max() < 0.5
    with pytest.raises(InputError, match="no propagation"):
        measured_front_speed(mesh, result)


def test_apd50_near_23_time_units():
    assert action_potential_duration(strip(10.0, 0.5, 0.25), x=5.0) == pytest.approx(23.0, rel=0.1)


def test_simple_variant_propagates_at_the_analytic_speed():
    mesh = strip(30.0, 1.0, 0.25)
    result = planar_run(mesh, 0.15, model=APParams(variant="simple"))
    assert measured_front_speed(mesh, result) == pytest.approx(front_speed(1.0, 0.15), rel=0.1)


@pytest.mark.parametrize("a", [0.15, 0.3])
def test_front_speed_at_the_default_lv_resolution_within_10_percent(a):
    """Default diffusivity on a slab whose spacing equals the default LV mesh's mean edge."""
    from simgen.meshes.ellipsoid import lv_ellipsoid
    from simgen.solver.simulate import SolverConfig

    h = lv_ellipsoid(2000, "tetra").mean_edge_length()
    assert abs(speed_error(slab(250.0, 12.0, 12.0, h), a, diffusivity=SolverConfig().diffusivity)) < 0.10

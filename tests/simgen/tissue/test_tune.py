"""A tissue in physical terms: conduction velocity (m/s) and APD90 (ms) measured on a strip."""

from __future__ import annotations

import math

import pytest

from shared.errors import TissueError
from shared.tissue import Material, TissueSpec
from shared.units import MS_PER_TIME_UNIT
from simgen.meshes.slab import strip
from simgen.solver.cells.aliev_panfilov import APParams
from simgen.solver.cells.mitchell_schaeffer import MSParams
from simgen.solver.simulate import SolverConfig
from simgen.solver.verification import measured_front_speed, planar_run
from simgen.tissue.tune import Physical, apd90, diffusivity_for_speed, physical, unit_speed

SOLVER = SolverConfig()


def _tissue(a: float = 0.15, D: float = 1.0, **kw) -> TissueSpec:
    return TissueSpec(name="t", healthy=Material(a=a, D=D), **kw)


def test_defaults_the_closed_form_assumes() -> None:
    assert SOLVER.diffusivity == 100.0 and MS_PER_TIME_UNIT == 12.9
    assert isinstance(SOLVER.model, APParams) and SOLVER.model.k == 8.0


@pytest.mark.parametrize("a", [0.15, 0.25])
def test_cv_matches_the_aliev_panfilov_closed_form(a: float) -> None:
    closed = math.sqrt(2 * 8.0 * 100.0) * (0.5 - a) / 12.9  # mm per time unit -> m/s
    result = physical(_tissue(a), SOLVER)
    assert isinstance(result, Physical) and result.cv_across is None
    assert result.cv == pytest.approx(closed, rel=0.03)


def test_default_tissue_conducts_near_one_metre_per_second() -> None:
    assert 1.0 < physical(TissueSpec(), SOLVER).cv < 1.15


def test_cv_scales_as_the_square_root_of_D() -> None:
    base = physical(_tissue(D=1.0), SOLVER).cv
    assert physical(_tissue(D=4.0), SOLVER).cv == pytest.approx(2 * base, rel=1e-9)
    assert physical(_tissue(D=0.25), SOLVER).cv == pytest.approx(base / 2, rel=1e-9)


def test_one_strip_measures_every_diffusivity() -> None:
    """The strip's rescaling (speed at D = sqrt(D) times the speed at 1) holds for a strip simulated at D = 4."""
    mesh = strip(60.0, 2.0, 0.25)
    direct = measured_front_speed(mesh, planar_run(mesh, 0.15, diffusivity=4.0))
    assert direct == pytest.approx(2 * unit_speed(SOLVER.model, 0.15), rel=0.02)


def test_cv_follows_the_solver_diffusivity() -> None:
    quarter = physical(_tissue(), SolverConfig(diffusivity=25.0)).cv
    assert quarter == pytest.approx(physical(_tissue(), SOLVER).cv / 2, rel=1e-9)


def test_cv_across_fibres_of_an_anisotropic_tissue() -> None:
    result = physical(_tissue(anisotropy=4.0), SOLVER)
    assert result.cv == pytest.approx(physical(_tissue(), SOLVER).cv, rel=1e-12)
    assert result.cv_across == pytest.approx(result.cv / math.sqrt(4.0), rel=1e-9)


def test_cv_across_from_the_solver_anisotropy_and_the_tissue_overriding_it() -> None:
    solver = SolverConfig(anisotropy=9.0)
    assert physical(_tissue(), solver).cv_across == pytest.approx(physical(_tissue(), solver).cv / 3, rel=1e-9)
    own = physical(_tissue(anisotropy=4.0), solver)
    assert own.cv_across == pytest.approx(own.cv / 2, rel=1e-9)


def test_default_apd90_is_a_few_hundred_ms() -> None:
    assert 200.0 < physical(TissueSpec(), SOLVER).apd < 450.0


@pytest.mark.parametrize("scale", [0.6, 1.5])
def test_apd_scale_scales_apd90(scale: float) -> None:
    base = physical(_tissue(), SOLVER).apd
    scaled = physical(_tissue(apd_scale=scale), SOLVER).apd
    assert (scaled < base) if scale < 1 else (scaled > base)
    assert scaled / base == pytest.approx(scale, rel=0.3)


def test_apd_scale_keeps_the_cv() -> None:
    base = physical(_tissue(), SOLVER)
    for scale in (0.6, 1.5):
        assert physical(_tissue(apd_scale=scale), SOLVER).cv == pytest.approx(base.cv, rel=0.01)


def test_cv_of_an_apd_scaled_tissue_is_its_own_speed() -> None:
    tissue = _tissue(a=0.25, apd_scale=0.5)
    own = math.sqrt(SOLVER.diffusivity) * unit_speed(SOLVER.model.apd_scaled(0.5), 0.25) / MS_PER_TIME_UNIT
    assert physical(tissue, SOLVER).cv == pytest.approx(own, rel=0.01)


def test_apd_scaled_models() -> None:
    ap = APParams().apd_scaled(2.0)
    assert (ap.eps0, ap.mu1, ap.eps_simple) == (0.001, 0.1, 0.005) and (ap.k, ap.mu2) == (8.0, 0.3)
    ms = MSParams().apd_scaled(1.5)
    assert ms.tau_close == pytest.approx(225.0) and ms.tau_in == 0.3 and ms.tau_open == 120.0


def test_mitchell_schaeffer_apd_scale() -> None:
    solver = SolverConfig(model=MSParams())
    base = physical(_tissue(), solver).apd
    scaled = physical(_tissue(apd_scale=1.5), solver).apd
    assert scaled / base == pytest.approx(1.5, rel=0.1)
    assert apd90(MSParams().apd_scaled(1.5), 0.15) == scaled


@pytest.mark.parametrize("cv, a", [(0.8, 0.15), (0.5, 0.2), (1.5, 0.12)])
def test_diffusivity_for_speed_inverts_the_speed(cv: float, a: float) -> None:
    D = diffusivity_for_speed(cv, a, SOLVER)
    assert 0 < D <= 4.0
    assert physical(_tissue(a, D), SOLVER).cv == pytest.approx(cv, rel=0.01)


def test_diffusivity_for_speed_of_the_default_tissue_is_one() -> None:
    cv = physical(TissueSpec(), SOLVER).cv
    assert diffusivity_for_speed(cv, 0.15, SOLVER) == pytest.approx(1.0, rel=1e-9)
    assert diffusivity_for_speed(cv, 0.15, SolverConfig(diffusivity=50.0)) == pytest.approx(2.0, rel=1e-9)


def test_non_conducting_tissue_is_refused() -> None:
    with pytest.raises(TissueError, match="a = 0.5 does not conduct"):
        physical(_tissue(a=0.5), SOLVER)
    with pytest.raises(TissueError, match="does not conduct"):
        diffusivity_for_speed(1.0, 0.5, SOLVER)


@pytest.mark.parametrize(("a", "apd_scale"), [(0.12, 0.75), (0.15, None), (0.2, 1.3), (0.25, 0.75)])
def test_the_learners_closed_form_speed_is_within_3_percent_of_the_strip(a: float, apd_scale: float | None) -> None:
    """shared.tissue.healthy_speed, the CV a tissue head is trained to, against the strip measurement."""
    from shared.tissue import healthy_speed

    tissue = TissueSpec(healthy=Material(a=a, D=0.7), apd_scale=apd_scale)
    solver = SolverConfig()
    assert healthy_speed(tissue, solver.diffusivity) == pytest.approx(physical(tissue, solver).cv, rel=0.03)

"""The tissue prior: seeded, prefix-stable draws that lie within the ranges a spec states."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shared.errors import ConfigError
from shared.tissue import APD_SCALE_RANGE, TissueSpec
from simgen.meshes.aha import aha_segments
from simgen.meshes.catalog import get_mesh
from simgen.solver.simulate import SolverConfig
from simgen.tissue.prior import MAX_DRAWS, RV_ANGLE, SEGMENT_NEIGHBOURS, WALL_HEIGHTS, TissuePrior, draw_tissues
from simgen.tissue.tune import physical

#: A prior with every optional distribution switched on, wide enough to exercise every range.
FULL = TissuePrior(
    count=40,
    seed=7,
    a=(0.12, 0.18),
    D=(0.5, 2.5),
    apd_scale=(0.7, 1.4),
    scars=(1, 3),
    placement="both",
    rv_share=0.5,
    radius=(6.0, 14.0),
    elongation=(1.2, 1.8),
    transmural=(0.5, 0.9),
    border_width=(1.0, 4.0),
    core_a=(0.45, 0.5),
    core_D=(0.05, 0.15),
    border_a=(0.25, 0.3),
    border_D=(0.4, 0.6),
    fibrosis=0.5,
    fibrosis_density=(0.1, 0.2),
    fibrosis_patch=(3.0, 5.0),
    anisotropy=(2.0, 6.0),
)


def _within(value: float, bounds: tuple[float, float]) -> bool:
    return bounds[0] <= value <= bounds[1]


def _scars(draws: list[TissueSpec]):
    return [scar for t in draws for scar in t.scars]


def test_draws_are_deterministic() -> None:
    first, again = draw_tissues(FULL), draw_tissues(TissuePrior(**{**FULL.__dict__}))
    assert first == again
    assert all(isinstance(t, TissueSpec) for t in first)


def test_names_number_the_draws() -> None:
    assert [t.name for t in draw_tissues(TissuePrior(count=3))] == ["draw-000", "draw-001", "draw-002"]
    named = TissuePrior(count=2, name="heart")
    assert named.names == ["heart-000", "heart-001"] == [t.name for t in draw_tissues(named)]


def test_raising_count_keeps_the_earlier_draws() -> None:
    few = draw_tissues(TissuePrior(**{**FULL.__dict__, "count": 5}))
    many = draw_tissues(FULL)
    assert len(few) == 5 and len(many) == FULL.count
    assert many[:5] == few


def test_different_seeds_draw_different_tissues() -> None:
    zero = draw_tissues(TissuePrior(**{**FULL.__dict__, "count": 6, "seed": 0}))
    one = draw_tissues(TissuePrior(**{**FULL.__dict__, "count": 6, "seed": 1}))
    assert all(a != b for a, b in zip(zero, one))
    assert [t.healthy for t in zero] != [t.healthy for t in one]


def test_every_draw_lies_within_its_ranges() -> None:
    draws = draw_tissues(FULL)
    for t in draws:
        assert _within(t.healthy.a, FULL.a) and _within(t.healthy.D, FULL.D)
        assert _within(t.apd_scale, FULL.apd_scale)
        assert _within(t.anisotropy, FULL.anisotropy)
        assert FULL.scars[0] <= len(t.scars) <= FULL.scars[1]
        if t.fibrosis is not None:
            assert _within(t.fibrosis.density, FULL.fibrosis_density)
            assert _within(t.fibrosis.patch, FULL.fibrosis_patch)
            assert 0 <= t.fibrosis.seed < 2**31
    scars = _scars(draws)
    for scar in scars:
        assert _within(scar.core.a, FULL.core_a) and _within(scar.core.D, FULL.core_D)
        assert _within(scar.border.a, FULL.border_a) and _within(scar.border.D, FULL.border_D)
        assert _within(scar.border_width, FULL.border_width)
        if scar.region == "wall":
            assert _within(scar.radius, FULL.radius)
            assert _within(scar.elongation, FULL.elongation)
            assert _within(scar.transmural, FULL.transmural)
            assert _within(scar.height, WALL_HEIGHTS)
            assert _within(scar.angle, (-RV_ANGLE, RV_ANGLE) if scar.ventricle == "rv" else (-180.0, 180.0))
        else:
            assert scar.region == "segments" and 1 <= len(scar.segments) <= 2
    # every scar count and both placements occur over 40 draws
    assert {len(t.scars) for t in draws} == {1, 2, 3}
    assert {s.region for s in scars} == {"wall", "segments"}
    assert {s.ventricle for s in scars if s.region == "wall"} == {"lv", "rv"}
    assert 0 < sum(t.fibrosis is not None for t in draws) < len(draws)


def test_fixed_ranges_give_fixed_values() -> None:
    prior = TissuePrior(count=4, a=(0.14, 0.14), D=(1.5, 1.5), apd_scale=(1.2, 1.2), scars=(2, 2), radius=(9.0, 9.0))
    for t in draw_tissues(prior):
        assert (t.healthy.a, t.healthy.D, t.apd_scale, len(t.scars)) == (0.14, 1.5, 1.2, 2)
        assert all(s.radius == 9.0 for s in t.scars)


def test_D_is_log_uniform() -> None:
    """Over [0.01, 1] half of a log-uniform D lies below 0.1 (a uniform one: 9 %)."""
    draws = draw_tissues(TissuePrior(count=400, D=(0.01, 1.0), scars=(0, 0)))
    D = np.array([t.healthy.D for t in draws])
    assert D.min() >= 0.01 and D.max() <= 1.0
    assert 0.4 < np.mean(D < 0.1) < 0.6
    assert abs(np.median(np.log(D)) - math.log(0.1)) < 0.3


def test_default_D_range_when_neither_D_nor_cv() -> None:
    prior = TissuePrior(count=30, scars=(0, 0))
    assert prior.D == (0.3, 3.0) and prior.cv is None
    assert all(0.3 <= t.healthy.D <= 3.0 for t in draw_tissues(prior))


def test_unset_optional_distributions_leave_settings_unset() -> None:
    for t in draw_tissues(TissuePrior(count=10)):
        assert t.apd_scale is None and t.anisotropy is None and t.fibrosis is None


def test_apd_scale_draws_lie_in_the_admissible_range() -> None:
    draws = draw_tissues(TissuePrior(count=50, apd_scale=APD_SCALE_RANGE, scars=(0, 0)))
    scales = [t.apd_scale for t in draws if t.apd_scale is not None]  # exactly 1 is stored as unset
    assert len(scales) >= 49 and all(_within(s, APD_SCALE_RANGE) for s in scales)


def test_segment_neighbours_are_symmetric_and_adjacent() -> None:
    assert sorted(SEGMENT_NEIGHBOURS) == list(range(1, 18))
    for segment, neighbours in SEGMENT_NEIGHBOURS.items():
        assert segment not in neighbours and neighbours
        for other in neighbours:
            assert segment in SEGMENT_NEIGHBOURS[other], (segment, other)
    # each listed pair shares a mesh edge on an LV
    mesh = get_mesh("lv", 4000, "tetra")
    seg = aha_segments(mesh)
    e = mesh.edges()
    touching = {(int(a), int(b)) for a, b in zip(seg[e[:, 0]], seg[e[:, 1]]) if a != b}
    for segment, neighbours in SEGMENT_NEIGHBOURS.items():
        for other in neighbours:
            assert (segment, other) in touching or (other, segment) in touching, (segment, other)


@pytest.mark.parametrize("extent, sizes", [((1, 1), {1}), ((2, 2), {2}), ((1, 2), {1, 2})])
def test_segment_scars_are_one_or_two_adjacent_segments(extent: tuple[int, int], sizes: set[int]) -> None:
    draws = draw_tissues(TissuePrior(count=40, scars=(1, 3), placement="segments", segments=extent))
    scars = _scars(draws)
    assert all(s.region == "segments" for s in scars)
    assert {len(s.segments) for s in scars} == sizes
    for s in scars:
        assert all(1 <= k <= 17 for k in s.segments)
        if len(s.segments) == 2:
            first, second = s.segments
            assert first < second and second in SEGMENT_NEIGHBOURS[first]
        assert s.ventricle is None and s.height is None and s.optional is None


def test_rv_share_zero_gives_lv_scars_only() -> None:
    scars = _scars(draw_tissues(TissuePrior(count=30, scars=(1, 3), rv_share=0.0)))
    assert scars and all(s.region == "wall" and s.ventricle == "lv" for s in scars)
    assert all(s.optional is None for s in scars)


def test_rv_share_one_gives_optional_rv_scars_only() -> None:
    scars = _scars(draw_tissues(TissuePrior(count=30, scars=(1, 3), rv_share=1.0)))
    assert scars and all(s.region == "wall" and s.ventricle == "rv" for s in scars)
    assert all(s.optional is True for s in scars)
    assert all(abs(s.angle) <= RV_ANGLE for s in scars)


@pytest.mark.parametrize("share, expected", [(0.0, 0), (1.0, 25)])
def test_fibrosis_probability(share: float, expected: int) -> None:
    draws = draw_tissues(TissuePrior(count=25, fibrosis=share))
    assert sum(t.fibrosis is not None for t in draws) == expected


def test_cv_range_gives_tissues_that_conduct_within_it() -> None:
    cv = (0.6, 1.2)
    solver = SolverConfig()
    draws = draw_tissues(TissuePrior(count=4, seed=3, a=(0.13, 0.17), cv=cv, scars=(0, 0)), solver)
    speeds = [physical(t, solver).cv for t in draws]
    for speed in speeds:
        assert cv[0] * 0.99 <= speed <= cv[1] * 1.01, speeds
    assert len({round(s, 4) for s in speeds}) == len(speeds)  # drawn, not fixed


def test_cv_range_follows_the_solver_diffusivity() -> None:
    """The same cv at half the base diffusivity needs twice the diffusivity scale."""
    prior = TissuePrior(count=2, cv=(0.8, 0.8), a=(0.15, 0.15), scars=(0, 0))
    full = draw_tissues(prior, SolverConfig())
    half = draw_tissues(prior, SolverConfig(diffusivity=50.0))
    for f, h in zip(full, half):
        assert h.healthy.D == pytest.approx(2 * f.healthy.D, rel=1e-4)


def test_cv_beyond_the_diffusivity_range_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"cv = \[4\.5, 5\.0\].*outside"):
        draw_tissues(TissuePrior(count=1, cv=(4.5, 5.0), scars=(0, 0)))


@pytest.mark.parametrize(
    "patch, match",
    [
        ({"a": (0.2, 0.12)}, r"\[tissue_prior\] a must be \[low, high\] with low <= high"),
        ({"radius": (10.0, 5.0)}, r"radius must be \[low, high\] with low <= high"),
        ({"a": (0.01, 0.2)}, r"\[tissue_prior\] a = \[0\.01, 0\.2\] outside the admissible range"),
        ({"D": (0.5, 5.0)}, r"\[tissue_prior\] D = \[0\.5, 5\.0\] outside the admissible range"),
        ({"apd_scale": (0.2, 1.0)}, r"apd_scale = .* outside the admissible range"),
        ({"cv": (0.01, 1.0)}, r"cv = .* outside the admissible range"),
        ({"anisotropy": (0.5, 2.0)}, r"anisotropy = .* outside the admissible range"),
        ({"D": (0.5, 1.0), "cv": (0.5, 1.0)}, r"give D .* or cv .*, not both"),
        ({"count": 0}, r"count must be an integer in 1\.\.1000"),
        ({"count": MAX_DRAWS + 1}, r"count must be an integer"),
        ({"count": True}, r"count must be an integer"),
        ({"seed": -1}, r"seed must be an integer >= 0"),
        ({"scars": (2, 5)}, r"scars must be \[low, high\] with 0 <= low <= high <= 3"),
        ({"scars": (2, 1)}, r"scars must be \[low, high\]"),
        ({"segments": (0, 2)}, r"segments must be \[low, high\] with 1 <= low <= high <= 2"),
        ({"rv_share": 1.5}, r"rv_share must be a probability"),
        ({"fibrosis": -0.1}, r"fibrosis must be a probability"),
        ({"placement": "apex"}, r"placement 'apex' is not one of"),
        ({"a": (0.15, 0.3), "border_a": (0.25, 0.35)}, r"healthy a = \[0\.15, 0\.3\] reaches the border zone"),
    ],
)
def test_invalid_priors_name_the_key(patch: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        TissuePrior(**patch)


def test_healthy_a_may_reach_the_border_without_scars() -> None:
    TissuePrior(a=(0.15, 0.3), border_a=(0.25, 0.35), scars=(0, 0))

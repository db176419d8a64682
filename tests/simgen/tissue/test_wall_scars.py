"""Wall scars placed in the heart's own coordinates, and diffuse patchy fibrosis."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from shared.errors import TissueError
from shared.mesh import Mesh
from shared.tissue import (
    LABEL_BORDER,
    LABEL_CORE,
    LABEL_FIBROSIS,
    LABEL_HEALTHY,
    FibrosisSpec,
    Material,
    ScarSpec,
    TissueSpec,
)
from simgen.meshes.aha import longitudinal_angular
from simgen.meshes.biventricular import BiVGeometry
from simgen.meshes.catalog import get_mesh
from simgen.tissue.fields import fibrosis_mask, scar_regions, tissue_fields, wall_centre


@pytest.fixture(scope="module")
def lv() -> Mesh:
    return get_mesh("lv", 2000, "tetra")


@pytest.fixture(scope="module")
def biv() -> Mesh:
    return get_mesh("biv", 2000, "tetra")


def _wall(**kw) -> ScarSpec:
    return ScarSpec(region="wall", **{"height": 0.5, "angle": 90.0, "radius": 12.0, **kw})


def _core(mesh: Mesh, scar: ScarSpec) -> np.ndarray:
    (core, border), *_ = scar_regions(mesh, TissueSpec(name="t", scars=(scar,)))
    return core


def _miss_mm(mesh: Mesh, node: int, height: float, angle: float) -> float:
    """How far (mm along the wall) ``node`` lies from ``height`` and ``angle``."""
    h, theta = longitudinal_angular(mesh)
    offset = mesh.points[node] - mesh.axis.apex
    along = offset @ mesh.axis.direction
    radial = np.linalg.norm(offset - along * mesh.axis.direction)
    turn = np.radians((theta[node] - angle + 180.0) % 360.0 - 180.0)
    return float(np.hypot((h[node] - height) * mesh.axis.length, turn * radial))


def _rv_free_wall(mesh: Mesh) -> np.ndarray:
    """Nodes of the default BiV outside the LV's epicardial spheroid: the RV free wall."""
    rx, ry, rz = BiVGeometry().lv.radii(1)
    p = mesh.points
    return (p[:, 0] / rx) ** 2 + (p[:, 1] / ry) ** 2 + (p[:, 2] / rz) ** 2 > 1.05


PLACES = [(0.2, 0.0), (0.5, 90.0), (0.5, -90.0), (0.7, 180.0), (0.8, -150.0), (0.35, 45.0)]


@pytest.mark.parametrize("height, angle", PLACES)
def test_lv_scar_centre_near_its_height_and_angle(lv: Mesh, height: float, angle: float) -> None:
    centre = wall_centre(lv, _wall(height=height, angle=angle))
    assert centre in set(lv.nodes("endocardium").tolist())
    assert _miss_mm(lv, centre, height, angle) < 0.75 * lv.mean_edge_length()
    h, theta = longitudinal_angular(lv)
    assert abs(h[centre] - height) < 0.05


@pytest.mark.parametrize("height, angle", PLACES)
def test_biv_lv_scar_centre_on_the_lv_endocardium(biv: Mesh, height: float, angle: float) -> None:
    centre = wall_centre(biv, _wall(height=height, angle=angle))
    assert centre in set(biv.nodes("lv_endocardium").tolist())
    assert _miss_mm(biv, centre, height, angle) < 0.75 * biv.mean_edge_length()


def test_lv_is_the_default_ventricle(biv: Mesh) -> None:
    assert wall_centre(biv, _wall()) == wall_centre(biv, _wall(ventricle="lv"))


@pytest.mark.parametrize("height, angle", [(0.5, 30.0), (0.7, -40.0), (0.6, 0.0), (0.4, 0.0)])
def test_rv_scar_lies_in_the_rv_free_wall(biv: Mesh, height: float, angle: float) -> None:
    scar = _wall(ventricle="rv", height=height, angle=angle, radius=10.0)
    centre = wall_centre(biv, scar)
    assert centre in set(biv.nodes("rv_endocardium").tolist())
    free = _rv_free_wall(biv)
    assert free[centre]
    core = _core(biv, scar)
    assert core.sum() >= 5 and free[core].mean() > 0.8


def test_rv_scar_in_the_septal_direction_lies_in_the_free_wall(biv: Mesh) -> None:
    scar = _wall(ventricle="rv", height=0.5, angle=0.0, radius=10.0)
    free = _rv_free_wall(biv)
    assert free[wall_centre(biv, scar)]
    assert free[_core(biv, scar)].mean() > 0.5


def test_optional_rv_scar_on_an_lv_is_left_out(lv: Mesh) -> None:
    scar = _wall(ventricle="rv", optional=True, border_width=4.0)
    assert wall_centre(lv, scar) is None
    (core, border), *_ = scar_regions(lv, TissueSpec(name="t", scars=(scar,)))
    assert not core.any() and not border.any()
    fields = tissue_fields(lv, TissueSpec(name="t", scars=(scar,)))
    assert np.all(fields.label == LABEL_HEALTHY) and np.all(fields.a == 0.15)


def test_rv_scar_on_an_lv_is_refused_unless_optional(lv: Mesh) -> None:
    with pytest.raises(TissueError, match="rv_endocardium"):
        tissue_fields(lv, TissueSpec(name="t", scars=(_wall(ventricle="rv"),)))
    with pytest.raises(TissueError, match="rv_endocardium"):
        tissue_fields(lv, TissueSpec(name="t", scars=(_wall(ventricle="rv", optional=False),)))


def test_subendocardial_scar_is_a_subset_nearer_the_endocardium(lv: Mesh) -> None:
    full, sub = _core(lv, _wall(transmural=1.0)), _core(lv, _wall(transmural=0.3))
    assert np.array_equal(full, _core(lv, _wall()))  # unset: transmural
    assert sub.sum() >= 3 and sub.sum() < full.sum()
    assert not (sub & ~full).any()
    endo = cKDTree(lv.points[lv.nodes("endocardium")])
    depth = endo.query(lv.points)[0]
    assert depth[sub].mean() < depth[full].mean()
    assert depth[sub].max() < depth[full].max()


def test_larger_radius_selects_a_superset(lv: Mesh) -> None:
    small, large = _core(lv, _wall(radius=8.0)), _core(lv, _wall(radius=16.0))
    assert small.sum() >= 3 and large.sum() > small.sum()
    assert not (small & ~large).any()


def test_elongation_stretches_the_scar_along_the_long_axis(lv: Mesh) -> None:
    round_, long_ = _core(lv, _wall(radius=10.0)), _core(lv, _wall(radius=10.0, elongation=2.0))
    assert not (round_ & ~long_).any()
    along = (lv.points - lv.axis.apex) @ lv.axis.direction
    extent = {k: float(np.ptp(along[c])) for k, c in (("round", round_), ("long", long_))}
    assert extent["long"] > 1.5 * extent["round"]
    assert extent["long"] <= 2 * 20.0 + 1e-9  # semi-axis radius * elongation each side
    # around the ventricle it keeps its width
    _, theta = longitudinal_angular(lv)
    spread = {k: float(np.ptp(theta[c])) for k, c in (("round", round_), ("long", long_))}
    assert spread["long"] < 1.5 * spread["round"]


def test_wall_scar_paints_core_and_border(lv: Mesh) -> None:
    scar = _wall(border_width=5.0, core=Material(a=0.45, D=0.05), border=Material(a=0.3, D=0.4))
    fields = tissue_fields(lv, TissueSpec(name="t", scars=(scar,)))
    core = _core(lv, scar)
    assert np.array_equal(fields.label == LABEL_CORE, core)
    assert np.all(fields.a[core] == 0.45) and np.all(fields.D[core] == 0.05)
    border = fields.label == LABEL_BORDER
    assert border.any() and np.all(fields.a[border] == 0.3)


# Fibrosis


@pytest.mark.parametrize("density", [0.1, 0.3, 0.6])
def test_fibrosis_covers_about_its_density(lv: Mesh, density: float) -> None:
    mask = fibrosis_mask(lv, FibrosisSpec(density=density, patch=4.0, seed=5))
    assert mask.dtype == np.bool_ and mask.shape == (lv.n_nodes,)
    assert abs(mask.mean() - density) < 0.1


@pytest.mark.parametrize("density, share", [(0.0, 0.0), (1.0, 1.0)])
def test_fibrosis_density_extremes(lv: Mesh, density: float, share: float) -> None:
    assert fibrosis_mask(lv, FibrosisSpec(density=density, patch=4.0)).mean() == share


def test_fibrosis_is_seeded(lv: Mesh) -> None:
    spec = FibrosisSpec(density=0.3, patch=4.0, seed=11)
    first = fibrosis_mask(lv, spec)
    assert np.array_equal(first, fibrosis_mask(lv, FibrosisSpec(density=0.3, patch=4.0, seed=11)))
    other = fibrosis_mask(lv, FibrosisSpec(density=0.3, patch=4.0, seed=12))
    assert (first != other).mean() > 0.2


def test_fibrosis_is_patchy(lv: Mesh) -> None:
    """Patches larger than the edges (~5 mm) make neighbouring nodes alike more often than chance
    (0.3^2 + 0.7^2 = 0.58), the more so the larger the patches."""
    e = lv.edges()
    alike = {}
    for patch in (2.0, 16.0):
        mask = fibrosis_mask(lv, FibrosisSpec(density=0.3, patch=patch, seed=2))
        alike[patch] = (mask[e[:, 0]] == mask[e[:, 1]]).mean()
    assert alike[16.0] > 0.78 and alike[16.0] > alike[2.0] + 0.15


def test_fibrosis_labels_and_material(lv: Mesh) -> None:
    fibrosis = FibrosisSpec(density=0.3, patch=4.0, seed=3, material=Material(a=0.28, D=0.25))
    fields = tissue_fields(lv, TissueSpec(name="f", fibrosis=fibrosis))
    mask = fibrosis_mask(lv, fibrosis)
    assert np.array_equal(fields.label == LABEL_FIBROSIS, mask)
    assert np.all(fields.label[~mask] == LABEL_HEALTHY)
    assert np.all(fields.a[mask] == 0.28) and np.all(fields.D[mask] == 0.25)
    assert np.all(fields.a[~mask] == 0.15) and np.all(fields.D[~mask] == 1.0)


def test_default_fibrosis_material(lv: Mesh) -> None:
    fibrosis = FibrosisSpec(density=0.5, patch=4.0)
    fields = tissue_fields(lv, TissueSpec(name="f", fibrosis=fibrosis))
    mask = fields.label == LABEL_FIBROSIS
    assert mask.any() and np.all(fields.a[mask] == fibrosis.material.a) and np.all(fields.D[mask] == 0.2)


def test_scars_override_fibrosis(lv: Mesh) -> None:
    fibrosis = FibrosisSpec(density=0.5, patch=4.0, seed=1)
    scar = _wall(radius=14.0, border_width=6.0)
    fields = tissue_fields(lv, TissueSpec(name="s", scars=(scar,), fibrosis=fibrosis))
    (core, border), *_ = scar_regions(lv, TissueSpec(name="s", scars=(scar,)))
    mask = fibrosis_mask(lv, fibrosis)
    assert (core & mask).any() and (border & mask).any()  # the test covers overlaps
    assert np.all(fields.label[core] == LABEL_CORE) and np.all(fields.a[core] == scar.core.a)
    assert np.all(fields.label[border] == LABEL_BORDER) and np.all(fields.a[border] == scar.border.a)
    rest = mask & ~core & ~border
    assert np.all(fields.label[rest] == LABEL_FIBROSIS)
    assert np.all(fields.label[~mask & ~core & ~border] == LABEL_HEALTHY)


@pytest.fixture(scope="module")
def resolutions() -> tuple[Mesh, Mesh, np.ndarray]:
    """One LV at two resolutions, and for each node of the coarse one its nearest node of the fine one."""
    coarse, fine = get_mesh("lv", 1000, "tetra"), get_mesh("lv", 4000, "tetra")
    return coarse, fine, cKDTree(fine.points).query(coarse.points)[1]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fibrotic_fraction_agrees_across_resolutions(resolutions, seed: int) -> None:
    coarse, fine, _ = resolutions
    spec = FibrosisSpec(density=0.3, patch=5.0, seed=seed)
    assert abs(fibrosis_mask(coarse, spec).mean() - fibrosis_mask(fine, spec).mean()) < 0.1


@pytest.mark.parametrize("patch", [4.0, 6.0, 8.0])
def test_fibrosis_pattern_lies_in_space(resolutions, patch: float) -> None:
    """Nearby nodes of the two resolutions are mostly alike (chance alone: 0.58 at density 0.3)."""
    coarse, fine, nearest = resolutions
    spec = FibrosisSpec(density=0.3, patch=patch, seed=4)
    assert (fibrosis_mask(coarse, spec) == fibrosis_mask(fine, spec)[nearest]).mean() > 0.75


def test_fibrosis_pattern_lies_in_space_at_any_patch_size(resolutions) -> None:
    coarse, fine, nearest = resolutions
    spec = FibrosisSpec(density=0.3, patch=7.99, seed=0)
    assert (fibrosis_mask(coarse, spec) == fibrosis_mask(fine, spec)[nearest]).mean() > 0.75


def test_too_fine_fibrosis_is_refused(lv: Mesh) -> None:
    with pytest.raises(TissueError, match="too small"):
        fibrosis_mask(lv, FibrosisSpec(density=0.3, patch=0.5))


@pytest.mark.parametrize(
    "kw, match",
    [({"density": 1.5, "patch": 4.0}, "density"), ({"density": 0.3, "patch": 0.0}, "patch")],
)
def test_fibrosis_spec_validation(kw: dict, match: str) -> None:
    with pytest.raises(TissueError, match=match):
        FibrosisSpec(**kw)


# ScarSpec validation


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"region": "sphere", "node": 1, "radius": 5.0, "height": 0.5}, r"\['height'\] apply to region = 'wall'"),
        ({"region": "sphere", "node": 1, "radius": 5.0, "ventricle": "lv"}, r"ventricle.*apply to region = 'wall'"),
        ({"region": "segments", "segments": (1,), "optional": True}, r"optional.*apply to region = 'wall'"),
        ({"region": "segments", "segments": (1,), "transmural": 0.5}, r"transmural.*'segments'"),
        ({"region": "wall", "angle": 0.0, "radius": 5.0}, "needs a height"),
        ({"region": "wall", "height": 0.5, "radius": 5.0}, "an angle"),
        ({"region": "wall", "height": 1.2, "angle": 0.0, "radius": 5.0}, r"height must lie in \[0, 1\]"),
        ({"region": "wall", "height": -0.1, "angle": 0.0, "radius": 5.0}, "height must lie in"),
        ({"region": "wall", "height": 0.5, "angle": 200.0, "radius": 5.0}, r"angle must lie in \[-180, 180\]"),
        ({"region": "wall", "height": 0.5, "angle": -181.0, "radius": 5.0}, "angle must lie in"),
        ({"region": "wall", "height": 0.5, "angle": 0.0, "radius": 5.0, "transmural": 0.0}, "transmural"),
        ({"region": "wall", "height": 0.5, "angle": 0.0, "radius": 5.0, "transmural": 1.5}, "transmural"),
        ({"region": "wall", "height": 0.5, "angle": 0.0, "radius": 5.0, "elongation": 0.0}, "elongation"),
        ({"region": "wall", "height": 0.5, "angle": 0.0, "radius": 0.0}, "radius must be > 0"),
        ({"region": "wall", "height": 0.5, "angle": 0.0, "radius": 5.0, "ventricle": "la"}, "ventricle 'la'"),
        ({"region": "wall", "height": float("nan"), "angle": 0.0, "radius": 5.0}, "height"),
    ],
)
def test_scar_spec_validation(kw: dict, match: str) -> None:
    with pytest.raises(TissueError, match=match):
        ScarSpec(**kw)


def test_valid_wall_scar_extremes() -> None:
    ScarSpec(region="wall", height=0.0, angle=-180.0, radius=1.0, transmural=1.0)
    ScarSpec(region="wall", height=1.0, angle=180.0, radius=1.0, transmural=1e-3, ventricle="rv", optional=False)

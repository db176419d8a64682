from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from shared.errors import TissueError
from shared.mesh import LongAxis, Mesh
from shared.tissue import LABEL_BORDER, LABEL_CORE, LABEL_HEALTHY, Material, ScarSpec, TissueSpec
from simgen.meshes.aha import aha_segments
from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.tissue.fields import tissue_fields


@pytest.fixture(scope="module", params=["tetra", "triangle"])
def lv(request: pytest.FixtureRequest) -> Mesh:
    return lv_ellipsoid(2000, request.param)


def _geodesic(mesh: Mesh, core: np.ndarray, boundary: bool = True) -> np.ndarray:
    """Shortest path along edges from the core by Bellman-Ford relaxation (reference): from its nodes, or from
    its boundary, halfway along each edge that leaves it."""
    e = mesh.edges()
    w = np.linalg.norm(mesh.points[e[:, 0]] - mesh.points[e[:, 1]], axis=1)
    i, j, w = np.concatenate([e[:, 0], e[:, 1]]), np.concatenate([e[:, 1], e[:, 0]]), np.concatenate([w, w])
    dist = np.full(mesh.n_nodes, np.inf)
    if boundary:
        leaving = core[i] & ~core[j]
        np.minimum.at(dist, j[leaving], 0.5 * w[leaving])
    else:
        dist[core] = 0.0
    while True:
        new = dist.copy()
        np.minimum.at(new, j, dist[i] + w)
        if np.array_equal(new, dist):
            return dist
        dist = new


def _equator_node(mesh: Mesh, angle: float = 0.0) -> int:
    """An epicardial node near height z = -20 at the given angle (radians)."""
    target = np.array([35.0 * np.cos(angle), 35.0 * np.sin(angle), -20.0])
    return int(np.argmin(np.linalg.norm(mesh.points - target, axis=1)))


def test_healthy(lv: Mesh) -> None:
    f = tissue_fields(lv, TissueSpec())
    assert f.a.dtype == np.float64 and f.D.dtype == np.float64 and f.label.dtype == np.int8
    assert f.a.shape == f.D.shape == f.label.shape == (lv.n_nodes,)
    assert np.all(f.a == 0.15) and np.all(f.D == 1.0) and np.all(f.label == LABEL_HEALTHY)


def test_custom_healthy_material(lv: Mesh) -> None:
    f = tissue_fields(lv, TissueSpec(healthy=Material(a=0.2, D=0.8)))
    assert np.all(f.a == 0.2) and np.all(f.D == 0.8)


@pytest.mark.parametrize("border_rule", ["boundary", "nodes"])
@pytest.mark.parametrize("by", ["node", "centre"])
def test_sphere_core_and_border_distances(lv: Mesh, by: str, border_rule: str) -> None:
    node = _equator_node(lv)
    centre = lv.points[node] + np.array([1.0, 2.0, 0.5])
    radius, width = 12.0, 6.0
    scar = (
        ScarSpec(region="sphere", node=node, radius=radius, border_width=width)
        if by == "node"
        else ScarSpec(region="sphere", centre=tuple(centre), radius=radius, border_width=width)
    )
    f = tissue_fields(lv, TissueSpec(name="s", scars=(scar,)), border=border_rule)
    origin = lv.points[node] if by == "node" else centre
    core = np.linalg.norm(lv.points - origin, axis=1) <= radius
    np.testing.assert_array_equal(f.label == LABEL_CORE, core)
    geo = _geodesic(lv, core, boundary=border_rule == "boundary")
    border = ~core & (geo <= width)
    np.testing.assert_array_equal(f.label == LABEL_BORDER, border)
    assert border.sum() > 10
    assert np.all(f.a[core] == scar.core.a) and np.all(f.D[core] == scar.core.D)
    assert np.all(f.a[border] == scar.border.a) and np.all(f.D[border] == scar.border.D)
    healthy = ~core & ~border
    assert np.all(f.a[healthy] == 0.15) and np.all(f.D[healthy] == 1.0)


def test_no_border_without_width(lv: Mesh) -> None:
    scar = ScarSpec(region="sphere", node=_equator_node(lv), radius=10.0)
    f = tissue_fields(lv, TissueSpec(scars=(scar,)))
    assert not np.any(f.label == LABEL_BORDER) and np.any(f.label == LABEL_CORE)


def test_segment_scar(lv: Mesh) -> None:
    scar = ScarSpec(region="segments", segments=(7, 8), border_width=5.0)
    f = tissue_fields(lv, TissueSpec(scars=(scar,)))
    seg = aha_segments(lv)
    np.testing.assert_array_equal(f.label == LABEL_CORE, np.isin(seg, [7, 8]))
    border = f.label == LABEL_BORDER
    assert border.any()
    assert set(np.unique(seg[border]).tolist()) <= {1, 2, 3, 6, 9, 12, 13, 14, 16}


def test_overlap_rules(lv: Mesh) -> None:
    node = _equator_node(lv)
    big = ScarSpec(
        region="sphere",
        node=node,
        radius=10.0,
        border_width=8.0,
        core=Material(a=0.5, D=0.1),
        border=Material(a=0.3, D=0.5),
    )
    small = ScarSpec(
        region="sphere",
        node=node,
        radius=5.0,
        border_width=15.0,
        core=Material(a=0.45, D=0.0),
        border=Material(a=0.35, D=0.6),
    )
    f = tissue_fields(lv, TissueSpec(scars=(big, small)))
    g = tissue_fields(lv, TissueSpec(scars=(small, big)))
    for name in ("a", "D", "label"):
        np.testing.assert_array_equal(getattr(f, name), getattr(g, name))
    d = np.linalg.norm(lv.points - lv.points[node], axis=1)
    geo_big, geo_small = _geodesic(lv, d <= 10.0), _geodesic(lv, d <= 5.0)
    # Cores win over borders; the small core lies in the big core: the higher a wins.
    core = d <= 10.0
    np.testing.assert_array_equal(f.label == LABEL_CORE, core)
    assert np.all(f.a[core] == 0.5) and np.all(f.D[core] == 0.1)
    # Nodes in both borders take the border with the higher a (0.35, the small scar's).
    both = ~core & (geo_big <= 8.0) & (geo_small <= 15.0)
    only_big = ~core & (geo_big <= 8.0) & (geo_small > 15.0)
    assert both.any()
    assert np.all(f.a[both] == 0.35) and np.all(f.D[both] == 0.6) and np.all(f.label[both] == LABEL_BORDER)
    assert np.all(f.a[only_big] == 0.3)


def test_overlap_tie_takes_lower_d(lv: Mesh) -> None:
    node = _equator_node(lv)
    one = ScarSpec(region="sphere", node=node, radius=8.0, core=Material(a=0.5, D=0.2))
    two = ScarSpec(region="sphere", node=node, radius=6.0, core=Material(a=0.5, D=0.05))
    f = tissue_fields(lv, TissueSpec(scars=(one, two)))
    d = np.linalg.norm(lv.points - lv.points[node], axis=1)
    assert np.all(f.D[d <= 6.0] == 0.05) and np.all(f.D[(d > 6.0) & (d <= 8.0)] == 0.2)


def test_empty_sphere_region(lv: Mesh) -> None:
    ok = ScarSpec(region="sphere", node=0, radius=5.0)
    far = ScarSpec(region="sphere", centre=(500.0, 0.0, 0.0), radius=10.0)
    with pytest.raises(TissueError, match=r"scar 1: .*selects no node"):
        tissue_fields(lv, TissueSpec(scars=(ok, far)))


def test_absent_segment(lv: Mesh) -> None:
    # Move the apex far down: every node then lies in the mid or basal ring.
    axis = LongAxis(apex=np.array([0.0, 0.0, -200.0]), base=np.array([0.0, 0.0, 15.0]), reference=np.eye(3)[0])
    shifted = dataclasses.replace(lv, axis=axis)
    assert aha_segments(shifted).min() >= 1 and aha_segments(shifted).max() <= 12
    with pytest.raises(TissueError, match=r"scar 0: .*segments \[17\].*selects no node"):
        tissue_fields(shifted, TissueSpec(scars=(ScarSpec(region="segments", segments=(17,)),)))


@pytest.mark.parametrize("node", [-1, 10**6])
def test_node_out_of_range(lv: Mesh, node: int) -> None:
    scar = ScarSpec(region="sphere", node=node, radius=5.0)
    with pytest.raises(TissueError, match=r"scar 0: sphere node .* out of range"):
        tissue_fields(lv, TissueSpec(scars=(scar,)))


def test_whole_heart_scar(lv: Mesh) -> None:
    scar = ScarSpec(region="segments", segments=tuple(range(1, 18)))
    with pytest.raises(TissueError, match=r"scar 0: whole-heart"):
        tissue_fields(lv, TissueSpec(scars=(scar,)))
    # Each scar alone is fine, together they exceed the limit.
    pair = (
        ScarSpec(region="segments", segments=(2, 3), border_width=5.0),
        ScarSpec(region="segments", segments=(5, 6), border_width=5.0),
    )
    tissue_fields(lv, TissueSpec(scars=pair[:1]), max_scar_fraction=0.3)
    with pytest.raises(TissueError, match=r"scars 0\.\.1: whole-heart.*together"):
        tissue_fields(lv, TissueSpec(scars=pair), max_scar_fraction=0.3)
    # A larger limit admits it.
    tissue_fields(lv, TissueSpec(scars=(scar,)), max_scar_fraction=1.0)


def test_invalid_inputs(lv: Mesh) -> None:
    with pytest.raises(TissueError, match="admissible range"):
        Material(a=0.9)
    with pytest.raises(TissueError, match="max_scar_fraction"):
        tissue_fields(lv, TissueSpec(), max_scar_fraction=0.0)


def test_no_conduction_anywhere_is_refused_naming_the_setting(lv: Mesh) -> None:
    blocked = TissueSpec(name="blocked", healthy=Material(D=0.0))
    with pytest.raises(TissueError, match=r"tissue 'blocked': D = 0 at every node"):
        tissue_fields(lv, blocked)
    scar = ScarSpec(region="sphere", node=0, radius=5.0, core=Material(a=0.5, D=0.2))
    assert tissue_fields(lv, dataclasses.replace(blocked, scars=(scar,))).D.max() == 0.2  # some conduction


def test_a_border_measured_from_the_core_boundary_is_as_wide_at_every_resolution() -> None:
    """The default scars' 5 mm border: from the core's boundary its share of the heart stays about the same from
    1,000 to 10,000 nodes; from the core's nodes (stores built before) it loses 40% at 1,000 nodes, whose 7.7 mm
    edges leave few nodes within 5 mm of a core node."""
    scar = ScarSpec(region="segments", segments=(8, 9), border_width=5.0)
    spec = TissueSpec(name="septal", scars=(scar,))
    shares = {}
    for nodes in (1000, 10_000):
        mesh = lv_ellipsoid(nodes, "tetra")
        for rule in ("boundary", "nodes"):
            label = tissue_fields(mesh, spec, border=rule).label
            shares[nodes, rule] = (label == LABEL_BORDER).sum() / (label == LABEL_CORE).sum()
    assert shares[1000, "nodes"] < 0.65 * shares[10_000, "nodes"]
    assert 0.85 < shares[1000, "boundary"] / shares[10_000, "boundary"] < 1.2
    with pytest.raises(TissueError, match="border"):
        tissue_fields(lv_ellipsoid(500, "tetra"), spec, border="cells")

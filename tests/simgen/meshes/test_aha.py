from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from shared.errors import MeshError
from shared.mesh import LongAxis, Mesh
from simgen.meshes.aha import APEX_CAP, aha_segments, estimate_axis, longitudinal_angular
from simgen.meshes.ellipsoid import lv_ellipsoid

# Default LV geometry: epicardial apex at z = -65, base plane at z = 15.
APEX_Z, BASE_Z = -65.0, 15.0


@pytest.fixture(scope="module", params=["tetra", "triangle"])
def lv(request: pytest.FixtureRequest) -> Mesh:
    return lv_ellipsoid(2000, request.param)


def _l(mesh: Mesh) -> np.ndarray:
    return (mesh.points[:, 2] - APEX_Z) / (BASE_Z - APEX_Z)


def _rotation(seed: int) -> np.ndarray:
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def test_known_positions() -> None:
    # Axis along z from 0 to 10, reference +x: anterior is d x r = +y.
    axis = LongAxis(apex=np.zeros(3), base=np.array([0.0, 0.0, 10.0]), reference=np.array([1.0, 0.0, 0.0]))
    cases = [  # (l, theta in degrees, expected segment)
        (0.9, 90, 1),
        (0.9, 30, 2),
        (0.9, -30, 3),
        (0.9, -90, 4),
        (0.9, -150, 5),
        (0.9, 150, 6),
        (0.5, 90, 7),
        (0.5, 30, 8),
        (0.5, -30, 9),
        (0.5, -90, 10),
        (0.5, -150, 11),
        (0.5, 150, 12),
        (0.2, 90, 13),
        (0.2, 10, 14),
        (0.2, -90, 15),
        (0.2, 180, 16),
        (0.05, 90, 17),
        (-0.1, 0, 17),
        (1.3, 30, 2),
    ]
    l, theta, expected = (np.array(c, dtype=float) for c in zip(*cases))
    t = np.radians(theta)
    pts = np.stack([5 * np.cos(t), 5 * np.sin(t), 10 * l], axis=1)
    surface = {"surface": np.arange(len(pts))}
    mesh = Mesh(points=pts, cells=np.array([[0, 1, 2]]), node_sets=surface, axis=axis)
    np.testing.assert_array_equal(aha_segments(mesh), expected.astype(np.int8))
    l_got, theta_got = longitudinal_angular(mesh)
    np.testing.assert_allclose(l_got, l, atol=1e-12)
    np.testing.assert_allclose(np.cos(np.radians(theta_got - theta)), 1.0, atol=1e-12)


def test_all_segments_with_plausible_shares(lv: Mesh) -> None:
    seg = aha_segments(lv)
    assert seg.dtype == np.int8 and seg.shape == (lv.n_nodes,)
    share = np.bincount(seg, minlength=18)[1:] / lv.n_nodes
    assert np.all(share[:16] > 0.03) and np.all(share[:16] < 0.12)
    assert 0.01 < share[16] < 0.08
    # Segments of one ring have about the same share.
    for ring in (share[0:6], share[6:12], share[12:16]):
        assert ring.max() / ring.min() < 1.3


def test_rings_follow_height(lv: Mesh) -> None:
    seg, l = aha_segments(lv), _l(lv)
    np.testing.assert_array_equal(seg == 17, l < APEX_CAP)
    assert np.all(l[seg == 17] < 0.1 + 1e-9)
    apical = (seg >= 13) & (seg <= 16)
    assert np.all((l[apical] >= APEX_CAP) & (l[apical] < 1 / 3))
    mid = (seg >= 7) & (seg <= 12)
    assert np.all((l[mid] >= 1 / 3) & (l[mid] < 2 / 3))
    assert np.all(l[seg <= 6] >= 2 / 3)
    assert np.all(seg[lv.nodes("base")] <= 6)


@pytest.mark.parametrize(
    ("direction", "expected"),
    [
        ((1.0, 0.0), {2, 3, 8, 9, 14}),  # reference -> septum
        ((0.0, 1.0), {1, 7, 13}),  # d x r -> anterior
        ((0.0, -1.0), {4, 10, 15}),  # inferior
        ((-1.0, 0.0), {5, 6, 11, 12, 16}),  # lateral
    ],
)
def test_circumferential_convention(lv: Mesh, direction: tuple[float, float], expected: set[int]) -> None:
    seg = aha_segments(lv)
    xy = lv.points[:, :2]
    cos = xy @ np.array(direction) / np.linalg.norm(xy, axis=1).clip(1e-9)
    near = (cos > np.cos(np.radians(20))) & (seg != 17)
    assert near.sum() > 20
    assert set(np.unique(seg[near]).tolist()) == expected


def test_estimate_axis_recovers_lv_axis(lv: Mesh) -> None:
    bare = dataclasses.replace(lv, axis=None)
    axis = estimate_axis(bare)
    angle = np.degrees(np.arccos(np.clip(axis.direction @ np.array([0.0, 0.0, 1.0]), -1, 1)))
    assert angle < 3.0
    assert abs(axis.apex[2] - APEX_Z) < 3.0 and abs(axis.base[2] - BASE_Z) < 3.0
    assert abs(axis.reference @ axis.direction) < 1e-12
    assert np.isclose(np.linalg.norm(axis.reference), 1.0)
    # Axis-aligned mesh: the estimated reference is x, as on the generated mesh.
    assert axis.reference[0] > 0.99
    assert np.mean(aha_segments(bare) == aha_segments(lv)) > 0.95


@pytest.mark.parametrize("seed", [0, 1])
def test_estimate_axis_rotated_and_flipped(lv: Mesh, seed: int) -> None:
    rot = _rotation(seed)
    flip = np.diag([1.0, 1.0, -1.0]) if seed else np.eye(3)  # apex at +z before rotating
    moved = Mesh(points=lv.points @ (rot @ flip).T, cells=lv.cells, node_sets=lv.node_sets)
    axis = estimate_axis(moved)
    true_direction = rot @ flip @ np.array([0.0, 0.0, 1.0])
    angle = np.degrees(np.arccos(np.clip(axis.direction @ true_direction, -1, 1)))
    assert angle < 3.0
    np.testing.assert_allclose(axis.apex, rot @ flip @ np.array([0.0, 0.0, APEX_Z]), atol=3.0)
    assert axis.reference @ axis.reference == pytest.approx(1.0)
    assert abs(axis.reference @ axis.direction) < 1e-12
    assert set(np.unique(aha_segments(moved)).tolist()) == set(range(1, 18))


def test_invalid_apex_cap(lv: Mesh) -> None:
    with pytest.raises(MeshError, match="apex_cap"):
        aha_segments(lv, apex_cap=0.5)

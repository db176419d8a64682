"""Topology helpers: row grouping and boundary faces against the row-wise ``np.unique`` reference."""

from __future__ import annotations

import numpy as np
import pytest

from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.meshes.topology import boundary_faces, group_rows, tet_faces


def reference_boundary_faces(tets: np.ndarray) -> np.ndarray:
    """The original row-wise implementation."""
    faces = tet_faces(tets)
    _, inverse, counts = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True)
    return faces[counts[inverse.ravel()] == 1]


@pytest.mark.parametrize("width", [3, 4])
def test_group_rows_matches_numpy_unique(width):
    rng = np.random.default_rng(0)
    rows = rng.integers(0, 5, size=(200, width))
    rows[:, 0] += 2**20 * (width == 4)  # large values force the lexsort path for width 4
    inverse, counts = group_rows(rows)
    _, ref_inverse, ref_counts = np.unique(rows, axis=0, return_inverse=True, return_counts=True)
    assert (counts[inverse] == ref_counts[ref_inverse.ravel()]).all()
    assert (inverse == ref_inverse.ravel()).all()
    np.testing.assert_array_equal(counts, ref_counts)


def test_group_rows_empty():
    inverse, counts = group_rows(np.zeros((0, 3), dtype=np.int64))
    assert len(inverse) == 0 and len(counts) == 0


# 2**21 + 1 nodes make N^3 overflow int64, so the offset case takes the lexsort path.
@pytest.mark.parametrize("offset", [0, 2**21])
def test_boundary_faces_matches_reference(offset):
    tets = lv_ellipsoid(500).cells.astype(np.int64) + offset
    faces = boundary_faces(tets)
    expected = reference_boundary_faces(tets)
    assert faces.dtype == np.int32
    np.testing.assert_array_equal(faces, expected)


def test_boundary_faces_drops_faces_shared_by_three_tets():
    # Three tets on the face (0, 1, 2): that face is non-manifold, not boundary.
    tets = np.array([[0, 1, 2, 3], [1, 0, 2, 4], [0, 1, 2, 5]])
    faces = boundary_faces(tets)
    np.testing.assert_array_equal(faces, reference_boundary_faces(tets))
    assert len(faces) == 9
    assert not (np.sort(faces, axis=1) == [0, 1, 2]).all(axis=1).any()


def test_boundary_faces_of_one_tet_are_outward():
    tets = np.array([[0, 1, 2, 3]])
    np.testing.assert_array_equal(boundary_faces(tets), [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


def test_boundary_faces_of_no_tets():
    faces = boundary_faces(np.zeros((0, 4), dtype=np.int64))
    assert faces.shape == (0, 3) and faces.dtype == np.int32

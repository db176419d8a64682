"""Anatomical region labels of a heart mesh, for stimulation sites named by region (:mod:`shared.sites`).

From a heart's node sets and long axis:

- the AHA segment of every left-ventricular node (:func:`simgen.meshes.aha.aha_segments`);
- the right ventricle's free wall: the nodes nearer the RV endocardium than
  the LV endocardium and nearer the epicardium than the LV endocardium (the
  septum, between the two cavities, fails the second test). Its nodes carry
  segment 0: AHA segments describe the left ventricle.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from shared.errors import MeshError
from shared.mesh import Mesh
from shared.sites import SiteLabels
from simgen.meshes.aha import aha_segments

__all__ = ["site_labels"]


def site_labels(mesh: Mesh) -> SiteLabels:
    """The :class:`~shared.sites.SiteLabels` of a heart mesh (its ``epicardium`` and ``endocardium`` sets
    required; biventricular meshes also ``lv_endocardium`` and ``rv_endocardium``)."""
    missing = [name for name in ("epicardium", "endocardium") if name not in mesh.node_sets]
    if missing:
        raise MeshError(f"mesh {mesh.name!r} has no {' or '.join(missing)} node set: it carries no heart regions")
    n = mesh.n_nodes
    epicardium, endocardium = _mask(mesh, "epicardium"), _mask(mesh, "endocardium")
    free_wall = np.zeros(n, bool)
    if "rv_endocardium" in mesh.node_sets and "lv_endocardium" in mesh.node_sets:
        d_lv, d_rv, d_epi = (_distance(mesh, name) for name in ("lv_endocardium", "rv_endocardium", "epicardium"))
        free_wall = (d_rv < d_lv) & (d_epi < d_lv)
    segment = np.where(free_wall, 0, aha_segments(mesh)).astype(np.int8)
    return SiteLabels(segment, epicardium, endocardium, free_wall)


def _mask(mesh: Mesh, name: str) -> NDArray[np.bool_]:
    mask = np.zeros(mesh.n_nodes, bool)
    mask[mesh.nodes(name)] = True
    return mask


def _distance(mesh: Mesh, name: str) -> NDArray[np.float64]:
    """Euclidean distance (mm) of every node from the nearest node of set ``name`` (inf for an empty set)."""
    nodes = mesh.nodes(name)
    if not len(nodes):
        return np.full(mesh.n_nodes, np.inf)
    return cKDTree(mesh.points[nodes]).query(mesh.points)[0]

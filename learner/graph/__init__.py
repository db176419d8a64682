"""Mesh graphs and their coarsening hierarchy."""

from __future__ import annotations

from learner.graph.hierarchy import Graph, MeshHierarchy, build_hierarchy, hierarchy_for_mesh

__all__ = ["Graph", "MeshHierarchy", "build_hierarchy", "hierarchy_for_mesh"]

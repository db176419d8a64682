"""Meshes that several simgen test modules make alike, made once per session."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from shared.mesh import Mesh


def _read_only(mesh: Mesh) -> Mesh:
    """``mesh`` with its arrays made read-only: a test that wrote into a shared mesh would fail, not pass on."""
    for array in (mesh.points, mesh.cells, *mesh.node_sets.values(), mesh.file_index, mesh.fibres, mesh.sheets):
        if array is not None:
            array.flags.writeable = False
    return mesh


@pytest.fixture(scope="session")
def shared_mesh() -> Callable[[str, int, str], Mesh]:
    """``get_mesh(source, nodes, kind)``, made once per session for each arguments and shared read-only.

    Resampling a real mesh takes seconds (``real:tof-biv`` to 1,000 tetrahedral nodes: about 8 s) and the
    resampling tests and the solver tests ask for the same ones; ``get_mesh`` is deterministic
    (``test_resampling_is_deterministic_and_keeps_good_meshes``).
    """
    from simgen.meshes.catalog import get_mesh

    made: dict[tuple[str, int, str], Mesh] = {}

    def mesh(source: str, nodes: int, kind: str) -> Mesh:
        if (source, nodes, kind) not in made:
            made[source, nodes, kind] = _read_only(get_mesh(source, nodes, kind))
        return made[source, nodes, kind]

    return mesh

from __future__ import annotations

import itertools
import tomllib

import numpy as np
import pytest
from scipy.sparse.csgraph import connected_components

from shared.config import to_mapping
from shared.errors import ConfigError, TissueError
from shared.mesh import Mesh
from shared.tissue import LABEL_BORDER, LABEL_CORE, Material, ScarSpec, TissueSpec
from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.meshes.topology import edge_graph
from simgen.tissue import default_settings, tissue_fields, tissue_spec_from_mapping


@pytest.fixture(scope="module", params=["tetra", "triangle"])
def lv(request: pytest.FixtureRequest) -> Mesh:
    return lv_ellipsoid(2000, request.param)


def _mask(mesh: Mesh, name: str) -> np.ndarray:
    mask = np.zeros(mesh.n_nodes, dtype=bool)
    mask[mesh.nodes(name)] = True
    return mask


def test_sixteen_named_settings() -> None:
    settings = default_settings()
    assert len(settings) == 16
    assert settings[0] == TissueSpec(name="healthy") and not settings[0].scars
    names = [s.name for s in settings]
    assert len(set(names)) == 16
    scars = settings[1:]
    assert all(s.name.startswith("scar-") and len(s.scars) == 1 for s in scars)
    regions = {tuple(sorted(s.scars[0].segments)) for s in scars}
    assert len(regions) == 15
    assert any(17 in r for r in regions)
    assert all(s.scars[0].region == "segments" and s.scars[0].border_width > 0 for s in scars)


def test_defaults_valid_on_lv(lv: Mesh) -> None:
    graph = edge_graph(lv)
    cores = []
    for spec in default_settings()[1:]:
        f = tissue_fields(lv, spec)
        fraction = np.mean(f.label > 0)
        assert 0.02 <= fraction <= 0.5, (spec.name, fraction)
        core = f.label == LABEL_CORE
        assert np.any(f.label == LABEL_BORDER), spec.name
        # Contiguous segments: one connected piece of the volume mesh; on the
        # closed surface, at most one piece on each of the epi- and endocardium
        # (the apical cap lies beyond the endocardial apex).
        walls = ("epicardium", "endocardium")
        pieces = [core] if lv.cell_type == "tetra" else [core & _mask(lv, w) for w in walls]
        for piece in filter(np.any, pieces):
            idx = np.flatnonzero(piece)
            n_parts, _ = connected_components(graph[idx][:, idx], directed=False)
            assert n_parts == 1, spec.name
        cores.append(core)
    for (i, one), (j, two) in itertools.combinations(enumerate(cores), 2):
        assert not np.array_equal(one, two), (i, j)


def test_mapping_example() -> None:
    data = {
        "name": "x",
        "scars": [{"region": "sphere", "node": 12, "radius": 15.0, "border_width": 5.0, "core": {"a": 0.5, "D": 0.1}}],
    }
    spec = tissue_spec_from_mapping(data)
    scar = ScarSpec(region="sphere", node=12, radius=15.0, border_width=5.0, core=Material(0.5, 0.1))
    assert spec == TissueSpec(name="x", scars=(scar,))


def test_mapping_from_toml() -> None:
    text = """
    name = "two"
    healthy = {a = 0.15, D = 1.0}
    [[scars]]
    region = "segments"
    segments = [1, 7]
    border_width = 5.0
    [[scars]]
    region = "sphere"
    centre = [0.0, 35.0, -20.0]
    radius = 10.0
    border = {a = 0.25, D = 0.7}
    """
    spec = tissue_spec_from_mapping(tomllib.loads(text))
    assert spec.scars[0].segments == (1, 7)
    assert spec.scars[1].centre == (0.0, 35.0, -20.0)
    assert spec.scars[1].border == Material(a=0.25, D=0.7)


def test_mapping_round_trip() -> None:
    for spec in default_settings():
        assert tissue_spec_from_mapping(to_mapping(spec)) == spec


@pytest.mark.parametrize(
    ("data", "match"),
    [
        ({"name": "x", "colour": "red"}, "unknown key"),
        ({"scars": [{"region": "sphere", "node": 1, "radius": 5.0, "width": 2.0}]}, r"scars\[0\].*unknown"),
        ({"scars": [{"region": "sphere", "node": 1, "radius": 5.0, "core": {"d": 0.1}}]}, r"core.*unknown"),
        ({"scars": [{"region": "sphere", "node": 1, "radius": "big"}]}, "expected a number"),
        ({"scars": [{"region": "cube", "node": 1, "radius": 5.0}]}, "not one of"),
    ],
)
def test_mapping_errors(data: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        tissue_spec_from_mapping(data)


def test_mapping_out_of_range_material() -> None:
    with pytest.raises(TissueError, match="admissible range"):
        tissue_spec_from_mapping({"scars": [{"region": "segments", "segments": [1], "core": {"a": 0.9}}]})
    with pytest.raises(TissueError, match="1..17"):
        tissue_spec_from_mapping({"scars": [{"region": "segments", "segments": [18]}]})

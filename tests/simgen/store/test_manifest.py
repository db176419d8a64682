from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from shared.errors import ConfigError, InputError, MeshError, StimulusError, TimeStepError, TissueError
from simgen.meshes import save_mesh, slab
from simgen.store import BuildSpec, Task, load_spec, make_plan, spec_from_mapping, spec_to_dict, validate_plan

SPECS = Path(__file__).resolve().parents[3] / "specs"


def _spec(**patch) -> BuildSpec:
    data = {
        "meshes": [{"id": "lv", "source": "lv", "nodes": 500}, {"id": "biv", "source": "biv", "nodes": 500}],
        "tissue": ["healthy", "scar-apex"],
        "custom_tissue": [{"name": "sphere", "scars": [{"region": "sphere", "node": 5, "radius": 10.0}]}],
        "sites": {"count": 23},
        "solver": {"frames": 10},
        "output": {"chunk_sites": 5, "sock_electrodes": 40},
    }
    return spec_from_mapping({**data, **patch})


@pytest.fixture(scope="module")
def plan():
    return make_plan(_spec())


def test_plan_contents(plan) -> None:
    assert list(plan.meshes) == ["lv", "biv"]
    assert [s.id for s in plan.subjects] == [
        "lv-healthy",
        "lv-scar-apex",
        "lv-sphere",
        "biv-healthy",
        "biv-scar-apex",
        "biv-sphere",
    ]
    assert len({s.id for s in plan.subjects}) == len(plan.subjects)
    assert all(plan.meshes[s.mesh_id].name == s.mesh_id for s in plan.subjects)
    assert plan.subject("biv-sphere").tissue.name == "sphere"
    for mesh_id, mesh in plan.meshes.items():
        sites = plan.sites[mesh_id]
        assert sites.dtype == np.int64 and sites.shape == (23,) and len(np.unique(sites)) == 23
        assert np.isin(sites, mesh.nodes("surface")).all()
        electrodes = plan.electrodes[mesh_id]
        assert len(electrodes) == 40 and np.isin(electrodes, mesh.nodes("epicardium")).all()
        assert np.all(np.diff(electrodes) > 0)
    validate_plan(plan)


def test_task_coverage(plan) -> None:
    assert len(plan.tasks) == 6 * 5
    assert len({t.key for t in plan.tasks}) == len(plan.tasks)
    for subject in plan.subjects:
        tasks = [t for t in plan.tasks if t.subject_id == subject.id]
        assert len(tasks) == plan.n_chunks(subject.id) == 5
        assert [t.chunk for t in tasks] == list(range(5))
        assert tasks[0].start == 0 and tasks[-1].stop == len(plan.sites[subject.mesh_id])
        assert all(a.stop == b.start for a, b in zip(tasks, tasks[1:]))
        assert all(t.stop - t.start == 5 for t in tasks[:-1]) and tasks[-1].stop - tasks[-1].start == 3
    # Order: subjects in plan order, chunks within a subject.
    assert [t.subject_id for t in plan.tasks[::5]] == [s.id for s in plan.subjects]
    assert Task("lv-healthy", 3, 15, 20).key == "lv-healthy/3"
    with pytest.raises(InputError, match="unknown subject 'lv-nothing'"):
        plan.subject("lv-nothing")


@pytest.mark.parametrize("method", ["farthest", "random"])
def test_deterministic(method: str) -> None:
    spec = _spec(sites={"count": 23, "method": method})
    a, b = make_plan(spec), make_plan(spec_from_mapping(spec_to_dict(spec)))
    c = make_plan(spec)
    for other in (b, c):
        assert all(np.array_equal(a.sites[m], other.sites[m]) for m in a.meshes)
        assert all(np.array_equal(a.electrodes[m], other.electrodes[m]) for m in a.meshes)
        assert all(np.array_equal(a.meshes[m].points, other.meshes[m].points) for m in a.meshes)
    assert a.tasks == c.tasks and a.subjects == c.subjects
    if method == "random":
        assert np.all(np.diff(a.sites["lv"]) > 0)
        reseeded = make_plan(dataclasses.replace(spec, seed=1))
        assert not np.array_equal(a.sites["lv"], reseeded.sites["lv"])


def test_farthest_sites_spread(plan) -> None:
    mesh, sites = plan.meshes["lv"], plan.sites["lv"]
    pts = mesh.points[sites]
    gaps = np.linalg.norm(pts[:, None] - pts[None], axis=-1) + np.eye(len(sites)) * 1e9
    # Farthest-point sites are far apart compared with the mesh spacing.
    assert gaps.min() > 2 * mesh.mean_edge_length()


def test_explicit_sites() -> None:
    spec = _spec(sites={"nodes": [7, 3, 11]})
    plan = make_plan(spec)
    assert plan.sites["lv"].tolist() == [7, 3, 11] and plan.sites["biv"].tolist() == [7, 3, 11]
    assert [t.key for t in plan.tasks[:2]] == ["lv-healthy/0", "lv-scar-apex/0"]
    with pytest.raises(StimulusError, match=r"node 100000 .*mesh 'lv'"):
        make_plan(_spec(sites={"nodes": [7, 100000]}))


def test_too_many_sites() -> None:
    with pytest.raises(InputError, match=r"mesh 'lv'.*cannot choose 400 sites.*'epicardium'"):
        make_plan(_spec(sites={"count": 400, "node_set": "epicardium"}))


@pytest.mark.parametrize("source", ["ellipsoid", "no/such/mesh.vtu"])
def test_unknown_mesh(source: str) -> None:
    with pytest.raises(MeshError, match="unknown mesh"):
        make_plan(_spec(meshes=[{"id": "x", "source": source}]))


def _slab_spec(tmp_path: Path, mesh_keys: str = "", output: str = "") -> Path:
    """A spec of the mesh file ``slab.vtu`` (a 20 x 10 x 4 mm slab), ``mesh_keys`` and ``output`` added."""
    save_mesh(slab(20.0, 10.0, 4.0, 2.0), tmp_path / "slab.vtu")
    spec_file = tmp_path / "spec.toml"
    spec_file.write_text(
        f'tissue = ["healthy"]\n[[meshes]]\nid = "slab"\nsource = "slab.vtu"\n{mesh_keys}'
        f'[sites]\ncount = 4\nnode_set = "all"\n[output]\nchunk_sites = 3\n{output}'
    )
    return spec_file


def test_a_slab_is_accepted_as_no_heart_without_a_sock(tmp_path: Path) -> None:
    plan = make_plan(load_spec(_slab_spec(tmp_path, "heart = false\n", "sock_electrodes = 0\n")))
    assert plan.meshes["slab"].name == "slab" and plan.electrodes["slab"].shape == (0,)
    assert sorted(plan.meshes["slab"].node_sets) == ["surface"]  # nothing detected
    assert [(t.start, t.stop) for t in plan.tasks] == [(0, 3), (3, 4)]
    validate_plan(plan)


def test_a_mesh_that_is_no_heart_is_refused(tmp_path: Path) -> None:
    with pytest.raises(MeshError, match=r"slab\.vtu: not a heart.*no ventricular cavity.*`heart = false`"):
        make_plan(load_spec(_slab_spec(tmp_path)))
    with pytest.raises(InputError, match=r"\[output\] sock_electrodes = 247: mesh 'slab' has no epicardium"):
        make_plan(load_spec(_slab_spec(tmp_path, "heart = false\n")))
    with pytest.raises(ConfigError, match=r"\['heart'\] apply to mesh files and real meshes, not to 'lv'"):
        spec_from_mapping({"meshes": [{"id": "lv", "heart": False}]})


def test_a_sock_larger_than_the_epicardium_is_refused() -> None:
    with pytest.raises(InputError, match=r"fewer than n_electrodes=5000.*\[output\] sock_electrodes"):
        make_plan(_spec(output={"sock_electrodes": 5000}, meshes=[{"id": "lv", "nodes": 500}]))


def test_no_sock() -> None:
    plan = make_plan(_spec(output={"chunk_sites": 5, "sock_electrodes": 0}, meshes=[{"id": "lv", "nodes": 500}]))
    assert plan.electrodes["lv"].shape == (0,)


def test_bad_scar() -> None:
    bad = {"name": "x", "scars": [{"region": "segments", "segments": [17], "core": {"a": 0.9, "D": 0.1}}]}
    with pytest.raises(TissueError, match="a=0.9"):
        _spec(custom_tissue=[bad])
    # Valid as data, impossible on the mesh: named by subject at validation.
    far = {"name": "far", "scars": [{"region": "sphere", "node": 100000, "radius": 5.0}]}
    plan = make_plan(_spec(custom_tissue=[far]))
    with pytest.raises(TissueError, match="subject 'lv-far'"):
        validate_plan(plan)


def test_unstable_dt() -> None:
    plan = make_plan(_spec(solver={"dt": 10.0}))
    with pytest.raises(TimeStepError, match=r"subject 'lv-healthy' \(mesh 'lv'\).*dt=10"):
        validate_plan(plan)


def test_validate_catches_bad_sites() -> None:
    plan = make_plan(_spec(sites={"nodes": [1, 2]}))
    plan.sites["lv"][0] = 10**6  # e.g. a plan edited after make_plan
    with pytest.raises(StimulusError, match="mesh 'lv'"):
        validate_plan(plan)


def test_demo_plan() -> None:
    plan = make_plan(load_spec(SPECS / "demo.toml"))
    assert len(plan.subjects) == 4 and len(plan.tasks) == 8 and len(plan.sites["lv"]) == 20
    validate_plan(plan)

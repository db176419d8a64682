from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import pytest
import zarr

from shared.errors import ConfigError, StimulusError, TissueError
from shared.tissue import TissueSpec
from simgen.solver.simulate import SolverConfig
from simgen.store import (
    BuildSpec,
    MeshEntry,
    OutputSpec,
    SiteSelection,
    load_spec,
    spec_from_mapping,
    spec_hash,
    spec_to_dict,
)
from simgen.store.layout import StoreMismatch

SPECS = Path(__file__).resolve().parents[3] / "specs"

SMALL = {
    "name": "small",
    "meshes": [{"id": "lv", "source": "lv", "nodes": 500}],
    "tissue": ["healthy", "scar-apex"],
    "custom_tissue": [
        {"name": "sphere", "scars": [{"region": "sphere", "node": 3, "radius": 8.0, "core": {"a": 0.4, "D": 0.2}}]}
    ],
    "sites": {"count": 12},
    "solver": {"frames": 10, "model": {"k": 8.0}},
    "output": {"chunk_sites": 5, "sock_electrodes": 40},
}

BAD_SCAR = {"region": "sphere", "node": 1, "radius": 5.0, "core": {"a": 0.9}}


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "spec.toml"
    path.write_text(text)
    return path


def test_demo_spec() -> None:
    spec = load_spec(SPECS / "demo.toml")
    assert [(m.id, m.source, m.nodes, m.kind) for m in spec.meshes] == [("lv", "lv", 1000, "tetra")]
    assert [s.name for s in spec.settings()] == ["healthy", "scar-anterior-mid", "scar-septal-basal", "scar-apex"]
    assert spec.sites.count == 20 and spec.output.chunk_sites == 10 and spec.solver.frames == 55


def test_default_spec() -> None:
    spec = load_spec(SPECS / "default.toml")
    assert [(m.id, m.source, m.nodes) for m in spec.meshes] == [
        ("lv", "lv", 2000),
        ("biv", "biv", 2000),
        ("lv-small", "lv", 1500),
    ]
    assert len(spec.settings()) == 16 and spec.settings()[0].name == "healthy"
    assert spec.sites.count == 200 and spec.output.chunk_sites == 64


def test_defaults() -> None:
    spec = spec_from_mapping({})
    assert spec == BuildSpec()
    assert spec.meshes == (MeshEntry("lv"),) and len(spec.settings()) == 16
    assert spec.solver == SolverConfig() and spec.sites == SiteSelection() and spec.output == OutputSpec()


def test_round_trip_and_hash() -> None:
    spec = spec_from_mapping(SMALL)
    data = spec_to_dict(spec)
    again = spec_from_mapping(json.loads(json.dumps(data)))
    assert again == spec
    assert spec_to_dict(again) == data
    assert spec_hash(again) == spec_hash(spec) == spec_hash(spec_from_mapping(SMALL))
    assert len(spec_hash(spec)) == 64 and int(spec_hash(spec), 16) >= 0
    # Defaults written out explicitly describe the same dataset.
    assert spec_hash(spec_from_mapping({})) == spec_hash(spec_from_mapping(spec_to_dict(BuildSpec())))


@pytest.mark.parametrize(
    "change",
    [
        lambda s: dataclasses.replace(s, seed=1),
        lambda s: dataclasses.replace(s, name="other"),
        lambda s: dataclasses.replace(s, meshes=(MeshEntry("lv", nodes=501),)),
        lambda s: dataclasses.replace(s, meshes=(MeshEntry("lv", nodes=500, kind="triangle"),)),
        lambda s: dataclasses.replace(s, tissue=("healthy",)),
        lambda s: dataclasses.replace(s, custom_tissue=(TissueSpec("x"),)),
        lambda s: dataclasses.replace(s, sites=SiteSelection(count=12, method="random")),
        lambda s: dataclasses.replace(s, sites=SiteSelection(nodes=(1, 2))),
        lambda s: dataclasses.replace(s, solver=dataclasses.replace(s.solver, dt=0.01)),
        lambda s: dataclasses.replace(s, output=dataclasses.replace(s.output, level=4)),
        lambda s: dataclasses.replace(s, output=dataclasses.replace(s.output, chunk_sites=6)),
    ],
)
def test_hash_changes(change) -> None:
    spec = spec_from_mapping(SMALL)
    assert spec_hash(change(spec)) != spec_hash(spec)


@pytest.mark.parametrize(
    ("text", "key"),
    [
        ("sede = 1\n", "sede"),
        ("[solver]\nframe = 10\n", "solver"),
        ("[solver.model]\nkk = 1.0\n", "solver.model"),
        ('[[meshes]]\nid = "lv"\nnode = 500\n', "meshes[0]"),
        ("[sites]\ncont = 3\n", "sites"),
        ('[[custom_tissue]]\nname = "x"\nscar = []\n', "custom_tissue[0]"),
    ],
)
def test_unknown_key(tmp_path: Path, text: str, key: str) -> None:
    with pytest.raises(ConfigError, match=r"unknown key") as info:
        load_spec(_write(tmp_path, text))
    bad = text.split("\n")[-2].split(" = ")[0]
    assert key in str(info.value) and bad in str(info.value) and "spec.toml" in str(info.value)


def test_wrong_type_and_bad_toml(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"output\.chunk_sites"):
        load_spec(_write(tmp_path, '[output]\nchunk_sites = "ten"\n'))
    with pytest.raises(ConfigError, match="invalid TOML"):
        load_spec(_write(tmp_path, "[output\n"))
    with pytest.raises(ConfigError, match="not found"):
        load_spec(tmp_path / "missing.toml")


@pytest.mark.parametrize(
    ("patch", "error", "match"),
    [
        ({"meshes": []}, ConfigError, "no meshes"),
        ({"meshes": [{"id": "a"}, {"id": "a"}]}, ConfigError, r"duplicate mesh ids \['a'\]"),
        ({"meshes": [{"id": "lv/1"}]}, ConfigError, "valid identifier"),
        ({"meshes": [{"id": "lv", "nodes": 0}]}, ConfigError, "nodes must be an integer >= 1"),
        ({"meshes": [{"id": "lv", "kind": "hex"}]}, ConfigError, "kind"),
        ({"tissue": ["healthy", "scar-nowhere"]}, ConfigError, r"unknown tissue setting 'scar-nowhere'.*scar-apex"),
        ({"tissue": ["default", "scar-apex"]}, ConfigError, r"duplicate tissue setting names \['scar-apex'\]"),
        ({"tissue": ["healthy"], "custom_tissue": [{"name": "healthy"}]}, ConfigError, "duplicate tissue"),
        ({"tissue": [], "custom_tissue": []}, ConfigError, "no tissue settings"),
        ({"custom_tissue": [{"name": "a b"}]}, ConfigError, "valid identifier"),
        (
            {"meshes": [{"id": "a"}, {"id": "a-b"}], "tissue": [], "custom_tissue": [{"name": "b-c"}, {"name": "c"}]},
            ConfigError,
            r"ambiguous",
        ),
        ({"output": {"chunk_sites": 0}}, ConfigError, "chunk_sites must be an integer >= 1"),
        ({"output": {"compressor": "zstd", "level": 30}}, ConfigError, r"level 30 out of range.*1\.\.22"),
        ({"output": {"compressor": "blosc", "level": 10}}, ConfigError, r"level 10 out of range.*0\.\.9"),
        ({"output": {"compressor": "lz4"}}, ConfigError, "compressor"),
        ({"output": {"sock_electrodes": -1}}, ConfigError, "sock_electrodes"),
        ({"sites": {"count": 0}}, ConfigError, "count must be an integer >= 1"),
        ({"sites": {"node_set": "septum"}}, ConfigError, "node_set 'septum'"),
        ({"sites": {"method": "grid"}}, ConfigError, "method"),
        ({"sites": {"nodes": [3, -1]}}, StimulusError, "-1"),
        ({"sites": {"nodes": [3, 4, 3]}}, StimulusError, r"duplicate stimulation nodes \[3\]"),
        ({"seed": -1}, ConfigError, "seed"),
        ({"custom_tissue": [{"name": "x", "scars": [BAD_SCAR]}]}, TissueError, "a=0.9"),
    ],
)
def test_invalid(patch: dict, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        spec_from_mapping({**SMALL, **patch})


def test_relative_mesh_path(tmp_path: Path) -> None:
    (tmp_path / "meshes").mkdir()
    path = _write(tmp_path, '[[meshes]]\nid = "p1"\nsource = "meshes/p1.vtu"\n[[meshes]]\nid = "g"\nsource = "biv"\n')
    spec = load_spec(path)
    assert spec.meshes[0].source == str((tmp_path / "meshes" / "p1.vtu").resolve())
    assert spec.meshes[1].source == "biv"
    # Resolution happens once: the stored spec round-trips unchanged.
    assert spec_from_mapping(spec_to_dict(spec), base_dir=Path("/elsewhere")) == spec


def test_a_default_written_out_is_the_same_spec_and_its_older_stores_resume(tmp_path, tiny_spec) -> None:
    from simgen.store.layout import layout_state
    from simgen.store.runner import build

    unset = tiny_spec()
    written = tiny_spec(solver={"frames": unset.solver.frames, "integrator": "auto", "backend": "numba"})
    assert written == unset and spec_hash(written) == spec_hash(unset)
    store = tmp_path / "s.zarr"
    build(unset, store, workers=1)
    # a store built before, from the spec with the defaults written out: its recorded hash is that spec's
    group = zarr.open_group(str(store), mode="r+")
    recorded = json.loads(json.dumps(dict(group.attrs)))
    recorded["spec"]["solver"]["integrator"] = "auto"
    recorded["spec_hash"] = hashlib.sha256(
        json.dumps(recorded["spec"], sort_keys=True, separators=(",", ":")).encode()
    ).hexdigest()
    group.attrs.update(recorded)
    assert recorded["spec_hash"] != spec_hash(unset)
    assert layout_state(str(store), spec_hash(unset)) == "resume"
    other = tiny_spec(solver={"frames": unset.solver.frames, "integrator": "imex"})
    with pytest.raises(StoreMismatch, match="different spec"):
        layout_state(str(store), spec_hash(other))

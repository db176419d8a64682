"""The simgen command line: help, mesh generation, simulation, errors."""

from __future__ import annotations

import re

import numpy as np
from typer.testing import CliRunner

from simgen.cli import app
from simgen.meshes.io import load_mesh
from simgen.meshes.quality import mesh_quality

runner = CliRunner()


def text(result) -> str:
    """Command output with rich's line wrapping undone."""
    return " ".join(result.output.split())


def test_help_lists_commands():
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0
    for verb in ("mesh", "simulate", "tissues", "demo"):
        assert verb in result.output


def test_mesh_command_writes_a_loadable_mesh(tmp_path):
    out = tmp_path / "lv.vtu"
    result = runner.invoke(app, ["mesh", str(out), "--nodes", "500"])
    assert result.exit_code == 0, result.output
    mesh = load_mesh(out)
    assert 450 < mesh.n_nodes < 550 and mesh.cell_type == "tetra"
    quality = mesh_quality(mesh)
    for label, value in [
        (r"smallest dihedral angle \(deg\)", f"{quality.min_angle:.1f}"),
        ("smallest altitude / mean edge", f"{quality.min_altitude_ratio:.3f}"),
    ]:
        assert re.search(rf"{label}\s+\S\s+{value}", result.output), result.output


def test_simulate_command_writes_outputs(tmp_path):
    result = runner.invoke(
        app, ["simulate", str(tmp_path), "--nodes", "500", "--sites", "0,7", "--tissue", "scar-apex"]
    )
    assert result.exit_code == 0, result.output
    data = np.load(tmp_path / "simulation.npz")
    assert data["u"].shape[:2] == (2, 55)
    assert (tmp_path / "activation.png").stat().st_size > 10_000


def test_demo_prints_its_summary_table_unwrapped(tmp_path):
    result = runner.invoke(app, ["demo", "--out", str(tmp_path), "--nodes", "600", "--sites-per-setting", "1"])
    assert result.exit_code == 0, result.output
    table = [line for line in result.output.splitlines() if line.startswith("|")]
    assert len(table) == 10 and max(map(len, table)) > 80 and all(line.endswith("|") for line in table)


def test_tissue_from_toml(tmp_path):
    spec = tmp_path / "scar.toml"
    spec.write_text('name = "blob"\n[[scars]]\nregion = "sphere"\nnode = 10\nradius = 12.0\n')
    result = runner.invoke(app, ["simulate", str(tmp_path / "o"), "--nodes", "500", "--tissue", str(spec)])
    assert result.exit_code == 0, result.output


def test_errors_are_reported_without_traceback(tmp_path):
    cases = [
        (["simulate", str(tmp_path), "--nodes", "500", "--sites", "99999"], "unknown stimulation node"),
        (["simulate", str(tmp_path), "--nodes", "500", "--dt", "1.0"], "unstable"),
        (["simulate", str(tmp_path), "--tissue", "no-such-scar"], "unknown tissue setting"),
        (["mesh", str(tmp_path / "x.vtu"), "--mesh", "heart.xyz"], "unknown mesh"),
    ]
    for args, message in cases:
        result = runner.invoke(app, args)
        assert result.exit_code == 2, result.output
        assert message in text(result)
        assert "Traceback" not in result.output


def test_tissues_lists_sixteen_settings():
    result = runner.invoke(app, ["tissues"])
    assert result.exit_code == 0
    assert "healthy" in result.output and "scar-apex" in result.output


def tiny_build(tmp_path):
    """Write a 2-chunk spec and build it with the CLI; returns (spec, store, result)."""
    spec = tmp_path / "tiny.toml"
    spec.write_text(
        'tissue = ["healthy"]\n[[meshes]]\nid = "lv"\nnodes = 500\n[sites]\ncount = 4\n'
        "[solver]\nframes = 6\n[output]\nchunk_sites = 2\nsock_electrodes = 30\n"
    )
    store = tmp_path / "s.zarr"
    return spec, store, runner.invoke(app, ["build", str(spec), "--store", str(store), "--workers", "1"])


def test_build_and_status_commands(tmp_path):
    spec, store, result = tiny_build(tmp_path)
    assert result.exit_code == 0, result.output
    assert "Dask dashboard: http" in text(result) and "2/2 chunks" in text(result)
    assert "simulated 2/2 chunks (lv-healthy/" in text(result) and "━" not in result.output  # a log: plain lines
    again = runner.invoke(app, ["build", str(spec), "--store", str(store)])
    assert "nothing to do, all 2 chunks done" in text(again)
    status = runner.invoke(app, ["status", str(store)])
    assert status.exit_code == 0 and "2/2 chunks done and sound (100%)" in text(status)
    spec.write_text(spec.read_text().replace("frames = 6", "frames = 7"))
    refused = runner.invoke(app, ["build", str(spec), "--store", str(store)])
    assert refused.exit_code == 2 and "different spec" in text(refused)
    bad = runner.invoke(app, ["status", str(tmp_path)])
    assert bad.exit_code == 2 and "not a Zarr store" in text(bad)


def test_sites_lists_site_indices_with_their_node_ids(tmp_path):
    from shared.reader import read_sites

    _, store, built = tiny_build(tmp_path)
    assert built.exit_code == 0
    listed = runner.invoke(app, ["sites", str(store), "lv-healthy"])
    assert listed.exit_code == 0, listed.output
    nodes = read_sites(store, "lv")
    rows = [line.split("│") for line in listed.output.splitlines() if line.count("│") == 6]
    assert [(int(r[1]), int(r[2])) for r in rows] == list(enumerate(nodes))
    unknown = runner.invoke(app, ["sites", str(store), "nobody"])
    assert unknown.exit_code == 2 and "unknown subject 'nobody'" in text(unknown)
    assert "Traceback" not in unknown.output


def test_verify_and_export_commands(tmp_path):
    _, store, built = tiny_build(tmp_path)
    assert built.exit_code == 0
    ok = runner.invoke(app, ["verify", str(store), "--sample", "2"])
    assert ok.exit_code == 0 and "0 problem(s)" in text(ok)
    exported = runner.invoke(app, ["export-vtk", str(store), "lv-healthy", "1", "--out", str(tmp_path / "vtk")])
    assert exported.exit_code == 0 and len(list((tmp_path / "vtk").glob("*.vtu"))) == 6
    (store / "subjects/lv-healthy/u/c/1/0/0").write_bytes(b"garbage")
    broken = runner.invoke(app, ["verify", str(store)])
    assert broken.exit_code == 1 and "chunk 1" in text(broken)


def test_add_subject_and_regenerate_commands(tmp_path):
    from shared.reader import read_mesh
    from simgen.meshes import lv_ellipsoid, save_mesh

    _, store, built = tiny_build(tmp_path)
    assert built.exit_code == 0
    patient = save_mesh(lv_ellipsoid(600), tmp_path / "patient.vtu")
    added = runner.invoke(
        app,
        [
            "add-subject",
            str(store),
            "--mesh",
            str(patient),
            "--id",
            "patient",
            "--tissue",
            "healthy",
            "--tissue",
            "scar-apex",
            "--workers",
            "1",
        ],
    )
    assert added.exit_code == 0, added.output
    status = text(runner.invoke(app, ["status", str(store)]))
    assert "patient-scar-apex" in status and "6/6 chunks done" in status
    regen = runner.invoke(
        app, ["regenerate", str(store), "--subjects", "patient-healthy", "--site-index", "3", "--workers", "1"]
    )
    assert regen.exit_code == 0 and "1/" in text(regen)
    surface = ["add-subject", str(store), "--mesh", "lv", "--id", "surface", "--kind", "triangle", "--nodes", "300"]
    added = runner.invoke(app, [*surface, "--tissue", "healthy", "--workers", "1"])
    assert added.exit_code == 0, added.output
    assert read_mesh(store, "surface").cells.shape[1] == 3
    unknown = runner.invoke(app, ["regenerate", str(store), "--subjects", "nobody"])
    assert unknown.exit_code == 2 and "nobody" in text(unknown)
    assert runner.invoke(app, ["verify", str(store), "--sample", "6"]).exit_code == 0

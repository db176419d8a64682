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
    assert data["v_mv"].shape[:2] == (2, 55) and -90 < data["v_mv"].min() < -70 < 0 < data["v_mv"].max() < 40
    np.testing.assert_allclose(data["times_ms"][:2], [7.74, 15.48])
    assert np.nanmax(data["activation_ms"]) > 50  # ms, not model time units
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
    assert status.exit_code == 0 and "2/2 chunks done (100%)" in text(status)
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


def test_a_mesh_file_is_used_as_it_is_and_results_come_back_on_its_node_ids(tmp_path):
    """A file with a node in no cell at id 5: simgen drops it to simulate, and answers on the file's ids."""
    import meshio

    from simgen.meshes import get_mesh

    lv = get_mesh("lv", 400)
    points = np.insert(lv.points, 5, lv.points.mean(axis=0), axis=0)
    cells = np.where(lv.cells >= 5, lv.cells + 1, lv.cells)
    path = tmp_path / "heart.vtu"
    meshio.write(path, meshio.Mesh(points, [("tetra", cells)]))
    out = tmp_path / "out"
    result = runner.invoke(app, ["simulate", str(out), "--mesh", str(path), "--sites", "10,300"])
    assert result.exit_code == 0, result.output
    data = np.load(out / "simulation.npz")
    assert data["v_mv"].shape == (2, 55, len(points)) and data["sites"].tolist() == [10, 300]
    assert np.isnan(data["v_mv"][:, :, 5]).all() and np.isfinite(data["v_mv"][:, :, 6:]).all()
    np.testing.assert_allclose(data["site_xyz"], points[[10, 300]])
    # node 10 of the file is node 9 of the mesh simulated: the activation there is 0, the stimulus's own
    assert data["activation_ms"][0, 10] == 0.0
    result = runner.invoke(app, ["simulate", str(out), "--mesh", str(path), "--sites", "5"])
    assert result.exit_code == 2 and "in no cell" in text(result)
    surface = tmp_path / "surface.vtu"
    meshio.write(
        surface,
        meshio.Mesh(get_mesh("lv", 400, "triangle").points, [("triangle", get_mesh("lv", 400, "triangle").cells)]),
    )
    result = runner.invoke(app, ["simulate", str(out), "--mesh", str(surface), "--kind", "tetra"])
    assert result.exit_code == 2 and "give a node count to resample it" in text(result)


def test_simulate_names_every_site_that_starts_no_wave(tmp_path):
    from simgen.meshes import get_mesh
    from simgen.tissue import default_settings, tissue_fields

    mesh = get_mesh("lv", 1000)
    fields = tissue_fields(mesh, {s.name: s for s in default_settings()}["scar-septal-basal"])
    core = np.flatnonzero(fields.label == 2)
    inside = int(core[np.argmin(np.linalg.norm(mesh.points[core] - mesh.points[core].mean(axis=0), axis=1))])
    args = ["simulate", str(tmp_path), "--nodes", "1000", "--tissue", "scar-septal-basal", "--sites", f"3,{inside}"]
    result = runner.invoke(app, args, terminal_width=200)
    assert result.exit_code == 0, result.output
    assert f"site {inside} starts no propagating wave" in text(result) and "site 3 starts" not in text(result)
    fraction = np.load(tmp_path / "simulation.npz")["activated_fraction"]
    assert fraction[0] > 0.5 > 0.05 > fraction[1]
    # paced in a scar on 7.7 mm edges: the resolution decides; site 3 lies in healthy tissue
    assert f"site {inside} is paced in a scar" in text(result) and "site 3 is paced" not in text(result)


def test_simulate_names_no_site_paced_in_a_scar_where_the_mesh_resolves_it(tmp_path):
    from simgen.meshes import get_mesh
    from simgen.tissue import default_settings, tissue_fields

    mesh = get_mesh("lv", 5000)
    assert mesh.mean_edge_length() < 4.5
    core = np.flatnonzero(tissue_fields(mesh, {s.name: s for s in default_settings()}["scar-septal-basal"]).label == 2)
    args = ["simulate", str(tmp_path), "--nodes", "5000", "--tissue", "scar-septal-basal", "--sites", str(core[0])]
    result = runner.invoke(app, args, terminal_width=200)
    assert result.exit_code == 0, result.output
    assert "paced in a scar" not in text(result)


def test_sites_by_position_and_region(tmp_path):
    from simgen.meshes import get_mesh

    mesh = get_mesh("biv", 1000)
    point = mesh.points[321] + 0.4
    xyz = ",".join(f"{c:.4f}" for c in point)
    args = ["simulate", str(tmp_path), "--mesh", "biv", "--nodes", "1000", "--site-xyz", xyz, "--site-region"]
    result = runner.invoke(app, [*args, "aha-4,rv-free-wall:endo"])
    assert result.exit_code == 0, result.output
    data = np.load(tmp_path / "simulation.npz")
    assert data["sites"][0] == 321 and len(data["sites"]) == 3
    np.testing.assert_allclose(data["site_xyz"][0], point, atol=1e-4)  # the stimulus is centred on the point
    out = tmp_path / "biv.vtu"
    assert runner.invoke(app, ["mesh", str(out), "--mesh", "biv", "--nodes", "1000"]).exit_code == 0
    again = runner.invoke(app, ["simulate", str(tmp_path / "b"), "--mesh", str(out), "--site-region", "aha-4"])
    assert again.exit_code == 0, again.output
    assert np.load(tmp_path / "b" / "simulation.npz")["sites"][0] == data["sites"][1]  # the file keeps its frame


def test_simulate_records_activation_maps_and_writes_a_time_series(tmp_path):
    args = ["simulate", str(tmp_path), "--nodes", "1000", "--tissue", "scar-septal-basal", "--sites", "3,400"]
    result = runner.invoke(app, [*args, "--observe", "surface", "--record", "activation", "--vtk", str(tmp_path / "v")])
    assert result.exit_code == 0, result.output
    recorded = np.load(tmp_path / "observations.npz")
    simulated = np.load(tmp_path / "simulation.npz")
    maps, observed = recorded["activation_ms"], recorded["observed"]
    assert "obs_mv" not in recorded and np.isnan(maps[:, ~observed]).all() and not np.isnan(maps[:, observed]).any()
    fired = simulated["v_mv"].max(axis=1) >= 0.8 * 100 - 80  # an action potential, not a scar core's bump
    np.testing.assert_allclose(
        maps[:, observed][fired[:, observed]],
        simulated["activation_ms"][:, observed][fired[:, observed]],
        rtol=1e-6,
    )
    assert np.isinf(maps[:, observed][~fired[:, observed]]).all() and np.isinf(maps).any()
    pvd = (tmp_path / "v" / "site-3.pvd").read_text()
    assert pvd.count("<DataSet") == 55 and (tmp_path / "v" / "site-400_0054.vtu").is_file()
    bad = runner.invoke(app, [*args, "--observe", "surface", "--record", "lat"], terminal_width=200)
    assert bad.exit_code == 2 and "--record: 'lat' is not one of potential, activation" in text(bad)


def test_simulate_writes_what_its_python_function_writes(tmp_path):
    """``simgen simulate`` parses and prints; :func:`simgen.simulate_files` writes the same files."""
    import simgen

    options = ["--nodes", "300", "--tissue", "scar-apex", "--sites", "0,40", "--observe", "epicardium"]
    result = runner.invoke(app, ["simulate", str(tmp_path / "cli"), *options])
    assert result.exit_code == 0, result.output
    run = simgen.simulate_files(tmp_path / "py", nodes=300, tissue="scar-apex", sites=[0, 40], observe="epicardium")
    assert run.summary().split(" -> ")[0] in text(result)
    for name in ("simulation.npz", "observations.npz"):
        with np.load(tmp_path / "cli" / name) as a, np.load(tmp_path / "py" / name) as b:
            assert sorted(a.files) == sorted(b.files)
            for key in a.files:
                np.testing.assert_array_equal(a[key], b[key], err_msg=f"{name} {key}")

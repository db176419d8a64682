"""docs/your-heart.md end to end: a real heart's recorded maps -> the shipped model personalised -> new pacing sites.

The recordings are simulated by ``simgen simulate --observe`` on the shipped MRI biventricle (a scar, 4
epicardial pacing sites, the 247-electrode sock, noise 0.02); nothing is trained.
"""

from __future__ import annotations

import meshio
import numpy as np
import torch
from typer.testing import CliRunner

from learner.cli import app as learner
from learner.metrics import spatial_cc
from simgen.cli import app as simgen

runner = CliRunner()
HEART = ["--mesh", "real:tof-biv", "--nodes", "1000", "--tissue", "scar-septal-basal"]
RECORDED, NEW = "0,713,460,681", "818,631"  # epicardial nodes of the 991-node heart, spread over it


def run(app, *args: str) -> str:
    result = runner.invoke(app, list(args))
    assert result.exit_code == 0, result.output
    return result.output


def test_a_real_heart_from_recorded_maps_to_new_pacing_sites(tmp_path):
    rec, truth = tmp_path / "recordings", tmp_path / "truth"
    run(simgen, "simulate", str(rec), *HEART, "--sites", RECORDED, "--observe", "electrodes", "--noise", "0.02")
    observations = np.load(rec / "observations.npz")
    assert observations["obs"].shape == (4, 55, 991) and observations["observed"].sum() == 247
    assert observations["sites"].tolist() == [0, 713, 460, 681] and len(observations["times"]) == 55

    run(
        learner,
        "personalize",
        "anatomies",
        "--observations",
        str(rec / "observations.npz"),
        "--out",
        str(tmp_path / "heart.pt"),
    )
    pred, vtk, png = tmp_path / "prediction.npz", tmp_path / "vtk", tmp_path / "prediction.png"
    run(
        learner,
        "predict",
        str(tmp_path / "heart.pt"),
        "--sites",
        NEW,
        "--out",
        str(pred),
        "--vtk",
        str(vtk),
        "--png",
        str(png),
    )
    u = np.load(pred)["u"]
    assert u.shape == (2, 55, 991)
    assert "activation_ms" in meshio.read(vtk / "site-818.vtu").point_data
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    run(simgen, "simulate", str(truth), *HEART, "--sites", NEW)
    true = np.load(truth / "simulation.npz")["u"]
    assert spatial_cc(u, true) > 0.8  # measured: 0.920 (MSE 0.016)

    # the same recordings as a mesh file and an observation file without the mesh's points and cells
    mesh = tmp_path / "heart.vtu"
    meshio.write(mesh, meshio.Mesh(observations["points"], [("tetra", observations["cells"])]))
    bare = tmp_path / "bare.npz"
    np.savez(bare, **{k: observations[k] for k in ("sites", "obs", "observed", "times")})
    run(
        learner,
        "personalize",
        "anatomies",
        "--mesh",
        str(mesh),
        "--observations",
        str(bare),
        "--out",
        str(tmp_path / "again.pt"),
    )
    first, again = (torch.load(tmp_path / f, weights_only=True) for f in ("heart.pt", "again.pt"))
    assert torch.allclose(first["c_mu"], again["c_mu"], atol=1e-5)


def fails(app, *args: str) -> str:
    """The one-line message of a command that must refuse its input (exit code 2)."""
    result = runner.invoke(app, list(args), terminal_width=200)
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    return " ".join(result.output.split())


def test_the_path_refuses_bad_input_with_one_line(tmp_path):
    lv = ["--mesh", "lv", "--nodes", "300"]
    assert "--observe: unknown node set 'sock'" in fails(
        simgen, "simulate", str(tmp_path / "x"), *lv, "--observe", "sock"
    )
    run(simgen, "simulate", str(tmp_path / "rec"), *lv, "--sites", "1,20", "--observe", "surface")
    full = np.load(tmp_path / "rec" / "observations.npz")
    bare, other = tmp_path / "bare.npz", tmp_path / "other.vtu"
    np.savez(bare, **{k: full[k] for k in ("sites", "obs", "observed", "times")})
    slow = tmp_path / "slow.npz"
    np.savez(slow, **{k: full[k] for k in ("sites", "obs", "observed")}, times=2 * full["times"])
    mesh = tmp_path / "lv.vtu"
    meshio.write(mesh, meshio.Mesh(full["points"], [("tetra", full["cells"])]))
    meshio.write(other, meshio.Mesh(full["points"] + 1.0, [("tetra", full["cells"])]))
    (tmp_path / "garbage.vtu").write_text("<VTKFile>not a mesh</VTKFile>\n")
    personalize = ("personalize", "anatomies", "--out", str(tmp_path / "p.pt"))
    cases = {
        ("--mesh", str(mesh)): "--mesh is the mesh of --observations: give --observations FILE too",
        ("--observations", str(bare)): "lacks array(s) ['points', 'cells']",
        ("--mesh", str(tmp_path / "none.vtu"), "--observations", str(bare)): "mesh file not found",
        ("--mesh", str(tmp_path / "garbage.vtu"), "--observations", str(bare)): "is not a readable mesh file",
        ("--mesh", str(other), "--observations", str(tmp_path / "rec" / "observations.npz")): "its points are not",
        ("--mesh", str(mesh), "--observations", str(slow)): "observations are at times 1.2, 2.4, ..., 66; the model",
    }
    for args, message in cases.items():
        assert message in fails(learner, *personalize, *args), args
    assert "is a shipped model, not a 'personalized' file" in fails(learner, "predict", "anatomies", "--sites", "1")

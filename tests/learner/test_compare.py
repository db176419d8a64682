"""learner compare: metrics of a prediction file against a simulation file, against values computed by hand."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from learner.cli import app
from learner.compare import compare_files
from learner.metrics import spatial_cc
from shared.errors import InputError
from simgen.meshes import get_mesh

runner = CliRunner()
TIMES_MS = 7.74 * np.arange(1, 56)


def sequences(n: int, delay: float) -> np.ndarray:
    """(2, 55, n) potentials in mV: two waves crossing the nodes in order, ``delay`` ms late."""
    arrival = np.linspace(10.0, 200.0, n)[None, None, :] + np.array([0.0, 30.0])[:, None, None] + delay
    u = 1.0 / (1.0 + np.exp(-(TIMES_MS[None, :, None] - arrival) / 5.0))
    return (100.0 * u - 80.0).astype(np.float32), arrival[:, 0, :]


@pytest.fixture()
def files(tmp_path):
    mesh = get_mesh("lv", 300)
    n = mesh.n_nodes
    true_mv, true_act = sequences(n, 0.0)
    pred_mv, pred_act = sequences(n, 6.0)
    np.savez(
        tmp_path / "sim.npz",
        sites=np.array([4, 9, 20]),
        site_xyz=mesh.points[[4, 9, 20]],
        times_ms=TIMES_MS,
        v_mv=np.concatenate([true_mv, true_mv[:1]]),
        activation_ms=np.concatenate([true_act, true_act[:1]]),
    )
    np.savez(
        tmp_path / "pred.npz",
        sites=np.array([9, 4]),
        site_xyz=mesh.points[[9, 4]],
        times_ms=TIMES_MS,
        v_mv=pred_mv[::-1],
        activation_ms=pred_act[::-1],
        points=mesh.points,
        cells=mesh.cells,
    )
    return tmp_path, true_mv, pred_mv


def test_sites_are_matched_by_node_and_scored_as_by_hand(files):
    folder, true_mv, pred_mv = files
    result = compare_files(folder / "pred.npz", folder / "sim.npz")
    assert result.sites.tolist() == [9, 4]
    # prediction row 0 is site 9, whose truth is the simulation's row 1
    u_pred, u_true = (pred_mv[1].astype(float) + 80) / 100, (true_mv[1].astype(float) + 80) / 100
    assert result.per_site[0]["mse"] == pytest.approx(float(np.mean((u_pred - u_true) ** 2)), rel=1e-4)
    assert result.per_site[0]["cc_spatial"] == pytest.approx(spatial_cc(u_pred, u_true), rel=1e-4)
    assert result.per_site[0]["act_error_ms"] == pytest.approx(6.0, abs=0.6)  # the 6 ms delay, found between frames
    assert result.overall["mse"]["n"] == 2


def test_the_command_prints_writes_and_draws(files):
    folder, _, _ = files
    out = folder / "cmp.json"
    args = [
        "compare",
        str(folder / "pred.npz"),
        str(folder / "sim.npz"),
        "--json",
        str(out),
        "--png",
        str(folder / "c.png"),
    ]
    result = runner.invoke(app, args, terminal_width=200)
    assert result.exit_code == 0, result.output
    assert "activation error (ms)" in result.output and "mean" in result.output
    saved = json.loads(out.read_text())
    assert saved["sites"] == [9, 4] and set(saved["overall"]) >= {"mse", "cc_spatial", "cc_temporal", "dc"}
    assert (folder / "c.png").read_bytes()[:4] == b"\x89PNG"


def test_a_simulation_at_other_frame_times_is_resampled(files):
    folder, true_mv, _ = files
    with np.load(folder / "sim.npz") as sim:
        arrays = dict(sim)
    arrays["times_ms"], arrays["v_mv"] = TIMES_MS[::2], arrays["v_mv"][:, ::2]
    np.savez(folder / "coarse.npz", **arrays)
    fine = compare_files(folder / "pred.npz", folder / "sim.npz").overall["cc_spatial"]["mean"]
    coarse = compare_files(folder / "pred.npz", folder / "coarse.npz").overall["cc_spatial"]["mean"]
    assert coarse == pytest.approx(fine, abs=0.02)


def test_files_that_do_not_match_are_refused(files, tmp_path):
    folder, _, _ = files
    with np.load(folder / "sim.npz") as sim:
        arrays = dict(sim)
    np.savez(folder / "other.npz", **{**arrays, "sites": np.array([1, 2, 3])})
    with pytest.raises(InputError, match=r"no sequence paced at node\(s\) \[9, 4\]"):
        compare_files(folder / "pred.npz", folder / "other.npz")
    np.savez(folder / "small.npz", **{**arrays, "v_mv": arrays["v_mv"][:, :, :10]})
    with pytest.raises(InputError, match="covers .* nodes and the simulation 10"):
        compare_files(folder / "pred.npz", folder / "small.npz")
    with pytest.raises(
        InputError, match=r"without-activation_ms.npz is not a simulation file: it lacks \['activation_ms'\]"
    ):
        compare_files(folder / "pred.npz", _without(folder, arrays, "activation_ms"))
    with pytest.raises(InputError, match="not found"):
        compare_files(folder / "none.npz", folder / "sim.npz")


def test_scores_that_would_lie_are_refused(files):
    folder, _, _ = files
    with pytest.raises(InputError, match="hold the same v_mv: a file compared with itself"):
        compare_files(folder / "pred.npz", folder / "pred.npz")
    with np.load(folder / "sim.npz") as sim:
        arrays = dict(sim)
    moved = arrays["site_xyz"].copy()
    moved[1] += [0.0, 12.0, 0.0]  # site 9 elsewhere: a renumbered copy of the mesh
    np.savez(folder / "renumbered.npz", **{**arrays, "site_xyz": moved})
    with pytest.raises(InputError, match=r"site 9 is at .* 12.0 mm apart: the files number the nodes of different"):
        compare_files(folder / "pred.npz", folder / "renumbered.npz")
    np.savez(folder / "u.npz", **{**arrays, "v_mv": (arrays["v_mv"] + 80.0) / 100.0})
    with pytest.raises(InputError, match=r"u.npz: v_mv ranges from .* never near rest\): give the transmembrane"):
        compare_files(folder / "pred.npz", folder / "u.npz")


def _without(folder, arrays, name):
    path = folder / f"without-{name}.npz"
    np.savez(path, **{k: v for k, v in arrays.items() if k != name})
    return path

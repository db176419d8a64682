"""bench.preconditioners: a growth row on a small mesh and the tables it prints."""

from __future__ import annotations

import pytest

from bench import preconditioners
from simgen.meshes import get_mesh


def test_growth_row_and_table() -> None:
    mesh = get_mesh("lv", 300, kind="tetra")
    row = {"target": 300, **preconditioners.growth_row(mesh, sites=2, repeat=1, warmup=False)}
    assert row["nodes"] == mesh.n_nodes and row["steps"] == 660 and row["cg_iterations"] >= 1
    iterations = row["steps"] * row["cg_iterations"]
    assert row["ns_per_node_iteration"] == pytest.approx(1e9 * row["wall_s"] / (mesh.n_nodes * iterations))
    double = {**row, "target": 600, "nodes": 2 * row["nodes"], "wall_s": 4 * row["wall_s"]}
    table = preconditioners.growth_table([row, double], sites=2)
    assert "| lv 600 |" in table
    assert table.rstrip().endswith(f"nodes^2.00 from {row['nodes']} to {2 * row['nodes']} nodes")
    assert table.splitlines()[-3].endswith("| 2.00 |")  # the exponent from the previous size


def test_amg_table_without_pyamg_says_how_to_get_it() -> None:
    assert "pip install pyamg" in preconditioners.amg_table(None)

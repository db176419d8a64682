"""``simgen add-subject`` with a real mesh file as a user brings it: in cm, no node sets, far too fine."""

from __future__ import annotations

import shutil

import meshio
import numpy as np
import zarr
from typer.testing import CliRunner

from simgen.cli import app
from simgen.meshes.shipped import unpacked


def test_add_subject_with_a_real_mesh_file(reference_store, tmp_path):
    store = tmp_path / "s.zarr"
    shutil.copytree(reference_store, store)
    with unpacked("real:cobiveco-mean-biv") as path:
        raw = meshio.read(path)
    patient = tmp_path / "patient.vtu"  # 24,991 nodes in cm, only the geometry
    meshio.write(patient, meshio.Mesh(raw.points / 10, [("triangle", raw.cells_dict["triangle"])]))
    args = ["add-subject", str(store), "--mesh", str(patient), "--id", "patient", "--tissue", "healthy"]
    result = CliRunner().invoke(app, [*args, "--nodes", "1000", "--workers", "1"])
    assert result.exit_code == 0, result.output
    group = zarr.open_group(str(store), path="meshes/patient", mode="r")
    assert group.attrs["cell_type"] == "tetra" and group.attrs["axis"] is not None
    points = group["points"][...]
    assert 900 <= len(points) <= 1100 and 90 < np.ptp(points, axis=0).max() < 130  # mm
    electrodes, epicardium = group["electrodes"][...], group["epicardium"][...]
    assert len(electrodes) == 40 and np.isin(electrodes, epicardium).all()
    assert len(group["endocardium"][...]) and not np.isin(group["endocardium"][...], epicardium).any()
    done = zarr.open_group(str(store), path="subjects/patient-healthy", mode="r")["done"][...]
    assert done.all()

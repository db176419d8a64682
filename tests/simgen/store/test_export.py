"""``export_vtk``: a ParaView time series of one stored simulation."""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET

import meshio
import numpy as np
import pytest
import zarr

from shared.errors import InputError
from simgen.solver.cells.aliev_panfilov import MS_PER_TIME_UNIT
from simgen.store.export import export_vtk


def test_export_writes_a_readable_time_series(reference_store, tmp_path):
    pvd = export_vtk(reference_store, "lv-scar-apex", 4, tmp_path / "out")
    g = zarr.open_group(str(reference_store), path="subjects/lv-scar-apex", mode="r")
    n_frames, n_nodes = g["u"].shape[1:]
    datasets = ET.parse(pvd).getroot().findall("./Collection/DataSet")
    assert len(datasets) == n_frames == len(list(pvd.parent.glob("*.vtu")))
    times = [float(d.get("timestep")) for d in datasets]
    assert np.allclose(times, g["times"][...] * MS_PER_TIME_UNIT)
    frame = 5
    mesh = meshio.read(pvd.parent / datasets[frame].get("file"))
    assert len(mesh.points) == n_nodes
    assert np.array_equal(mesh.point_data["u"], g["u"][4, frame])
    assert np.allclose(mesh.point_data["V_mV"], 100.0 * g["u"][4, frame] - 80.0)
    assert np.allclose(mesh.point_data["activation_ms"], g["activation"][4] * MS_PER_TIME_UNIT, equal_nan=True)
    assert np.array_equal(mesh.point_data["label"], g["label"][...])
    assert np.array_equal(mesh.point_data["a"], g["a"][...])


@pytest.mark.parametrize(
    "subject, site, match",
    [
        ("lv-nope", 0, "unknown subject 'lv-nope'"),
        ("lv-healthy", 6, "out of range"),
        ("lv-healthy", -1, "out of range"),
    ],
)
def test_bad_subject_or_site_is_refused(reference_store, tmp_path, subject, site, match):
    with pytest.raises(InputError, match=match):
        export_vtk(reference_store, subject, site, tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_unfinished_chunk_is_refused(reference_store, tmp_path):
    store = tmp_path / "s.zarr"
    shutil.copytree(reference_store, store)
    zarr.open_group(str(store), path="subjects/lv-healthy", mode="r+")["done"][1] = 0
    with pytest.raises(InputError, match="chunk 1 is not done"):
        export_vtk(store, "lv-healthy", 3, tmp_path / "out")
    assert export_vtk(store, "lv-healthy", 2, tmp_path / "out").exists()

"""ParaView time series: one .vtu per frame with its fields, listed in a .pvd with the frame times."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import meshio
import numpy as np

from shared.vtk import write_time_series
from simgen.meshes import get_mesh


def test_a_time_series_lists_every_frame_with_its_time_and_fields(tmp_path):
    mesh = get_mesh("lv", 300)
    n, times = mesh.n_nodes, np.array([7.74, 15.48, 23.22])
    frames = {"V_mV": np.arange(3 * n, dtype=np.float32).reshape(3, n)}
    static = {"activation_ms": np.linspace(0, 50, n)}
    pvd = write_time_series(tmp_path, "site-4", mesh.points, mesh.cells, times, frames, static)
    entries = ET.parse(pvd).getroot().find("Collection").findall("DataSet")
    assert [float(e.get("timestep")) for e in entries] == times.tolist()
    last = meshio.read(tmp_path / entries[-1].get("file"))
    np.testing.assert_array_equal(last.point_data["V_mV"], frames["V_mV"][2])
    np.testing.assert_allclose(last.point_data["activation_ms"], static["activation_ms"])
    assert last.cells[0].type == "tetra" and len(last.points) == n

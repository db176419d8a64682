"""Reader accessors: one subject's potential, activation times, frame times and the solver settings."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import zarr

from shared.errors import InputError, SchemaError
from shared.reader import (
    check_store,
    read_activation,
    read_rows,
    read_solver_settings,
    read_times,
    read_u,
    subject_array,
    subject_attrs,
)
from shared.units import MS_PER_TIME_UNIT


def test_arrays_of_a_subject(tiny_store):
    g = zarr.open_group(str(tiny_store), path="subjects/lv-scar-apex", mode="r")
    u = read_u(tiny_store, "lv-scar-apex")
    np.testing.assert_array_equal(u, g["u"][...])
    np.testing.assert_array_equal(read_u(tiny_store, "lv-scar-apex", [9, 0, 5]), u[[9, 0, 5]])
    np.testing.assert_array_equal(read_activation(tiny_store, "lv-scar-apex", [3]), g["activation"][[3]])
    np.testing.assert_array_equal(read_rows(subject_array(tiny_store, "lv-scar-apex", "u"), []), u[:0])
    times = read_times(tiny_store, "lv-scar-apex")
    np.testing.assert_array_equal(times, g["times"][...])
    np.testing.assert_allclose(read_times(tiny_store, "lv-scar-apex", "ms"), times * MS_PER_TIME_UNIT)
    with pytest.raises(InputError, match="unknown time unit 's'"):
        read_times(tiny_store, "lv-scar-apex", "s")


def test_solver_settings_are_the_spec_table(tiny_store):
    settings = read_solver_settings(tiny_store)
    assert settings["frames"] == 12 and settings["output_interval"] == 2.0


def test_unknown_subject_is_named(tiny_store):
    for read in (subject_attrs, read_u, read_times):
        with pytest.raises(InputError, match=r"unknown subject 'lv-nobody' in store"):
            read(tiny_store, "lv-nobody")


def test_times_in_ms_of_a_version_1_store(tiny_store, tmp_path, as_version_1):
    store = tmp_path / "v1.zarr"
    shutil.copytree(tiny_store, store)
    as_version_1(store)
    assert "time_ms" not in zarr.open_group(str(store), path="subjects/lv-healthy", mode="r")
    np.testing.assert_allclose(read_times(store, "lv-healthy", "ms"), read_times(tiny_store, "lv-healthy", "ms"))


@pytest.mark.parametrize("root", [None, "{not json"], ids=["missing", "not-json"])
def test_a_store_without_readable_root_metadata_is_named_with_the_repair(tmp_path, root):
    store = tmp_path / "s.zarr"
    (store / "meshes").mkdir(parents=True)
    if root is not None:
        (store / "zarr.json").write_text(root)
    with pytest.raises(SchemaError, match=rf"s\.zarr.*zarr\.json.*`simgen repair {store} --spec SPEC`"):
        check_store(store)

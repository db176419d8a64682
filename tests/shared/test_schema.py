"""The store contract: CF attributes from the schema, version checks, the canonical split."""

from __future__ import annotations

from collections import Counter

import pytest

from shared.errors import SchemaError
from shared.schema import (
    READABLE_VERSIONS,
    SCHEMA_VERSION,
    SUBJECT_ARRAYS,
    SchemaWarning,
    array_attributes,
    check_schema_version,
)
from shared.split import SPLIT_FRACTIONS, canonical_part


def test_data_arrays_list_the_coordinates_along_their_dimensions():
    assert array_attributes(SUBJECT_ARRAYS, "u") == {
        "units": "1",
        "long_name": "transmembrane potential u, dimensionless (V = 100 u - 80 mV)",
        "coordinates": "times time_ms x y z",
    }
    assert array_attributes(SUBJECT_ARRAYS, "activation")["coordinates"] == "x y z"
    assert array_attributes(SUBJECT_ARRAYS, "activation")["units"] == "12.9 ms"
    assert "coordinates" not in array_attributes(SUBJECT_ARRAYS, "time_ms")  # a coordinate itself
    assert all(spec.units and spec.long_name for spec in SUBJECT_ARRAYS.values())


def test_current_version_passes_silently(recwarn):
    assert check_schema_version({"schema_version": SCHEMA_VERSION}, "s.zarr", write=True) == SCHEMA_VERSION
    assert not recwarn.list


@pytest.mark.parametrize("version, lacks", [(1, "the metadata of version 2"), (2, "what version 3 added: sharding")])
def test_older_versions_are_read_with_a_warning_and_never_written(version, lacks):
    assert READABLE_VERSIONS == (1, 2, 3) and SCHEMA_VERSION == 3
    with pytest.warns(SchemaWarning, match=f"s.zarr has schema_version {version}: read without {lacks}"):
        assert check_schema_version({"schema_version": version}, "s.zarr") == version
    with pytest.raises(SchemaError, match=r"writes version 3 only.*`simgen build SPEC --store s.zarr --force`"):
        check_schema_version({"schema_version": version}, "s.zarr", write=True)


@pytest.mark.parametrize(
    "attrs, match",
    [
        ({}, "no schema_version attribute: not a simgen dataset store$"),
        ({"spec": {}}, r"no schema_version attribute.*restored with `simgen repair s\.zarr`"),
        ({"schema_version": 4}, "reads versions 1, 2, 3"),
    ],
)
def test_unknown_or_missing_version_is_refused(attrs, match):
    with pytest.raises(SchemaError, match=match):
        check_schema_version(attrs, "s.zarr")


def test_canonical_split_is_a_fixed_function_of_the_id():
    # pinned: a change of the rule would move the subjects of every store built since
    assert [canonical_part(s) for s in ("lv-healthy", "lv-b-healthy", "patient-scar-apex")] == [
        "train",
        "validation",
        "test",
    ]
    counts = Counter(canonical_part(f"subject-{i}") for i in range(20000))
    for part, fraction in SPLIT_FRACTIONS.items():
        assert abs(counts[part] / 20000 - fraction) < 0.01, part

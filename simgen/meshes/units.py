"""Length units of mesh files: from the file, from the caller, or inferred from the heart's size.

Meshes are in millimetres inside simgen. A file's coordinates are scaled by
its millimetres per unit, taken in this order:

1. ``units`` given by the caller (a build spec's ``units = "cm"``);
2. the file's own metadata: a field (meshio ``field_data``) or a constant point-data
   array named ``mm_per_unit`` (what :func:`simgen.meshes.io.save_mesh` writes), or a
   field ``units`` / ``length_unit`` holding ``"mm"``, ``"cm"`` or ``"m"``;
3. for a heart, the extent of the nodes in cells: a heart is about 50-150 mm
   long, so the largest side of the bounding box in :data:`HEART_EXTENT_MM`
   (40-250 mm) means mm, ten times smaller means cm and a thousand times
   smaller means m. Any other extent is ambiguous and refused. A mesh that is
   no heart (``--no-heart``: a slab) has no size to infer from: mm.

When the caller's units and the file's disagree, the file is refused.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from shared.errors import MeshError

__all__ = [
    "MM_PER_UNIT",
    "HEART_EXTENT_MM",
    "UNIT_KEY",
    "UNITS_HINT",
    "Units",
    "file_units",
    "infer_units",
    "mm_per_unit",
]

Units = Literal["mm", "cm", "m"]

#: Millimetres per coordinate unit.
MM_PER_UNIT: dict[str, float] = {"mm": 1.0, "cm": 10.0, "m": 1000.0}

#: Largest bounding-box side, in mm, that an inferred unit must give (inclusive).
HEART_EXTENT_MM = (40.0, 250.0)

#: How a user gives a mesh file's unit: the commands' option and the spec's key.
UNITS_HINT = '--units mm|cm|m (a build spec: units = "mm", "cm" or "m" in its [[meshes]] entry)'

#: Name of the metadata array holding millimetres per unit.
UNIT_KEY = "mm_per_unit"
_NAMED_KEYS = ("units", "length_unit")


def file_units(field_data: Mapping[str, Any], point_data: Mapping[str, Any], where: str) -> Units | None:
    """The units a file declares (see the module docstring), or ``None``."""
    for data in (field_data, point_data):
        if UNIT_KEY in data:
            values = np.unique(np.asarray(data[UNIT_KEY], dtype=np.float64))
            named = [u for u, scale in MM_PER_UNIT.items() if len(values) == 1 and values[0] == scale]
            if not named:
                raise MeshError(f"{where}: {UNIT_KEY} = {values.tolist()} is not one of {list(MM_PER_UNIT.values())}")
            return named[0]  # type: ignore[return-value]
    for key in _NAMED_KEYS:
        if key in field_data:
            value = str(np.asarray(field_data[key]).ravel()[0]).strip().lower()
            if value not in MM_PER_UNIT:
                raise MeshError(f"{where}: field {key!r} = {value!r} is not one of {list(MM_PER_UNIT)}")
            return value  # type: ignore[return-value]
    return None


def infer_units(points: NDArray[np.float64], where: str) -> Units:
    """Units from the largest bounding-box side, or :class:`MeshError` when it fits no unit."""
    extent = float(np.ptp(points, axis=0).max()) if len(points) else 0.0
    lo, hi = HEART_EXTENT_MM
    for unit, scale in MM_PER_UNIT.items():
        if lo <= extent * scale <= hi:
            return unit  # type: ignore[return-value]
    ranges = ", ".join(f"{lo / s:g}-{hi / s:g} {u}" for u, s in MM_PER_UNIT.items())
    raise MeshError(
        f"{where}: cannot infer the length unit from the mesh extent {extent:g} (a heart spans {ranges}); "
        f"give the unit: {UNITS_HINT}"
    )


def mm_per_unit(
    points: NDArray[np.float64],
    declared: Units | None,
    given: str | None,
    where: str,
    infer: bool = True,
) -> tuple[float, str]:
    """Millimetres per unit and where the unit came from (``"given"``, ``"file"``, ``"inferred"`` from
    ``points``, the nodes in cells, or ``"assumed"`` mm when not ``infer``: a mesh that is no heart)."""
    if given is not None and given not in MM_PER_UNIT:
        raise MeshError(f"{where}: units {given!r} is not one of {list(MM_PER_UNIT)}")
    if given is not None and declared is not None and given != declared:
        raise MeshError(f"{where}: the file says its unit is {declared!r} but {given!r} was given")
    if given is not None:
        return MM_PER_UNIT[given], "given"
    if declared is not None:
        return MM_PER_UNIT[declared], "file"
    if not infer:
        return 1.0, "assumed"
    return MM_PER_UNIT[infer_units(points, where)], "inferred"

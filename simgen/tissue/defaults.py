"""The default tissue settings (healthy + 15 scars) and loading specs from TOML tables.

Like the paper's benchmark, each mesh is simulated under 16 settings: healthy
tissue and 15 scars, each a set of contiguous AHA segments (see
:mod:`simgen.meshes.aha`) at a different location: anterior, septal, inferior
and lateral walls at basal, mid and apical level, two scars spanning two
levels, and the apical cap. Every scar has a 5 mm border zone.
"""

from __future__ import annotations

from typing import Any

from shared.config import from_mapping, load_toml
from shared.errors import InputError
from shared.tissue import DEFAULT_SCARS, Material, ScarSpec, TissueSpec

__all__ = [
    "SCAR_CORE",
    "BORDER_ZONE",
    "BORDER_WIDTH",
    "DEFAULT_SCARS",
    "default_settings",
    "tissue_spec_from_mapping",
    "named_setting",
]

#: Scar core: does not propagate, strongly reduced coupling.
SCAR_CORE = Material(a=0.5, D=0.1)
#: Border zone: slowed conduction.
BORDER_ZONE = Material(a=0.3, D=0.5)
#: Border zone width (mm, geodesic).
BORDER_WIDTH = 5.0


def default_settings() -> list[TissueSpec]:
    """The 16 default settings: ``"healthy"`` first, then the scars of :data:`DEFAULT_SCARS`."""
    scars = [
        TissueSpec(
            name=name,
            scars=(
                ScarSpec(
                    region="segments",
                    segments=segments,
                    core=SCAR_CORE,
                    border=BORDER_ZONE,
                    border_width=BORDER_WIDTH,
                ),
            ),
        )
        for name, segments in DEFAULT_SCARS.items()
    ]
    return [TissueSpec(name="healthy"), *scars]


def tissue_spec_from_mapping(data: dict[str, Any]) -> TissueSpec:
    """A :class:`TissueSpec` from a TOML/JSON table, strictly.

    Example (TOML)::

        name = "x"
        scars = [{region = "sphere", node = 12, radius = 15.0, border_width = 5.0,
                  core = {a = 0.5, D = 0.1}}]

    Unknown keys and wrong types raise :class:`shared.errors.ConfigError`;
    out-of-range values raise :class:`shared.errors.TissueError`.
    """
    return from_mapping(TissueSpec, data)


def named_setting(tissue: str) -> TissueSpec:
    """One of :func:`default_settings` by name, or the setting a ``.toml`` file holds."""
    specs = {s.name: s for s in default_settings()}
    if tissue in specs:
        return specs[tissue]
    if tissue.endswith(".toml"):
        return tissue_spec_from_mapping(load_toml(tissue))
    raise InputError(f"unknown tissue setting {tissue!r}: use one of {sorted(specs)} or a .toml file")

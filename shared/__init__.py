"""Contract between simgen and learner: mesh and tissue types, config loading, errors."""

from __future__ import annotations

from shared.config import from_mapping, load_toml, to_mapping
from shared.errors import (
    ConfigError,
    DamagedData,
    InputError,
    MeshError,
    SchemaError,
    StimulusError,
    TimeStepError,
    TissueError,
)
from shared.mesh import NODE_SETS, LongAxis, Mesh
from shared.tissue import HEALTHY, Material, ScarSpec, TissueFields, TissueSpec

__all__ = [
    "ConfigError",
    "DamagedData",
    "InputError",
    "MeshError",
    "SchemaError",
    "StimulusError",
    "TimeStepError",
    "TissueError",
    "LongAxis",
    "Mesh",
    "NODE_SETS",
    "HEALTHY",
    "Material",
    "ScarSpec",
    "TissueFields",
    "TissueSpec",
    "from_mapping",
    "load_toml",
    "to_mapping",
]

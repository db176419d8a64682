"""Tissue model: AHA segments, scar regions and per-node tissue fields."""

from __future__ import annotations

from simgen.tissue.aha import APEX_CAP, SEGMENT_NAMES, aha_segments, estimate_axis, longitudinal_angular
from simgen.tissue.defaults import (
    BORDER_WIDTH,
    BORDER_ZONE,
    DEFAULT_SCARS,
    SCAR_CORE,
    default_settings,
    tissue_spec_from_mapping,
)
from simgen.tissue.fields import scar_regions, tissue_fields

__all__ = [
    "APEX_CAP",
    "SEGMENT_NAMES",
    "aha_segments",
    "estimate_axis",
    "longitudinal_angular",
    "BORDER_WIDTH",
    "BORDER_ZONE",
    "DEFAULT_SCARS",
    "SCAR_CORE",
    "default_settings",
    "tissue_spec_from_mapping",
    "scar_regions",
    "tissue_fields",
]

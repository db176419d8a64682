"""Tissue model: AHA segments, scar regions, per-node tissue fields, the tissue prior and physical read-outs."""

from __future__ import annotations

from simgen.meshes.aha import APEX_CAP, SEGMENT_NAMES, aha_segments, estimate_axis, longitudinal_angular
from simgen.tissue.defaults import (
    BORDER_WIDTH,
    BORDER_ZONE,
    DEFAULT_SCARS,
    SCAR_CORE,
    default_settings,
    named_setting,
    tissue_spec_from_mapping,
)
from simgen.tissue.fields import fibrosis_mask, scar_regions, tissue_fields, wall_centre
from simgen.tissue.prior import TissuePrior, draw_tissues
from simgen.tissue.tune import Physical, physical

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
    "named_setting",
    "scar_regions",
    "tissue_fields",
    "fibrosis_mask",
    "wall_centre",
    "TissuePrior",
    "draw_tissues",
    "Physical",
    "physical",
]

"""Dataset builds: the build spec (TOML) and the deterministic build plan derived from it."""

from __future__ import annotations

from simgen.store.manifest import (
    Plan,
    Subject,
    SubjectSetup,
    Task,
    make_plan,
    select_sites,
    sock_electrodes,
    validate_plan,
)
from simgen.store.spec import (
    BuildSpec,
    MeshEntry,
    OutputSpec,
    SiteSelection,
    load_spec,
    spec_from_mapping,
    spec_hash,
    spec_to_dict,
)

__all__ = [
    "BuildSpec",
    "MeshEntry",
    "OutputSpec",
    "SiteSelection",
    "load_spec",
    "spec_from_mapping",
    "spec_hash",
    "spec_to_dict",
    "Plan",
    "Subject",
    "SubjectSetup",
    "Task",
    "make_plan",
    "select_sites",
    "sock_electrodes",
    "validate_plan",
]

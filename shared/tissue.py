"""Tissue types: declarative scar specifications and the per-node fields they produce.

A :class:`TissueSpec` is pure data (it round-trips through TOML/JSON); simgen
turns it into :class:`TissueFields` on a given mesh.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from shared.errors import TissueError

__all__ = [
    "Material",
    "ScarSpec",
    "TissueSpec",
    "TissueFields",
    "HEALTHY",
    "A_RANGE",
    "D_RANGE",
    "LABEL_HEALTHY",
    "LABEL_BORDER",
    "LABEL_CORE",
    "DEFAULT_SCARS",
    "DEFAULT_SETTING_NAMES",
]

#: Admissible excitability ``a`` (healthy 0.15; 0.5 and above does not propagate).
A_RANGE = (0.05, 0.5)
#: Admissible diffusivity scale (multiplies the solver's base diffusivity).
D_RANGE = (0.0, 1.0)

LABEL_HEALTHY, LABEL_BORDER, LABEL_CORE = 0, 1, 2

#: Name -> AHA segments of the 15 default scars (simgen.tissue builds them; readers need their names).
DEFAULT_SCARS: dict[str, tuple[int, ...]] = {
    "scar-anterior-basal": (1,),
    "scar-anterior-mid": (7,),
    "scar-anterior-apical": (13,),
    "scar-septal-basal": (2, 3),
    "scar-septal-mid": (8, 9),
    "scar-septal-apical": (14,),
    "scar-inferior-basal": (4,),
    "scar-inferior-mid": (10,),
    "scar-inferior-apical": (15,),
    "scar-lateral-basal": (5, 6),
    "scar-lateral-mid": (11, 12),
    "scar-lateral-apical": (16,),
    "scar-anterior-basal-mid": (1, 7),
    "scar-inferior-mid-apical": (10, 15),
    "scar-apex": (17,),
}
#: The 16 settings a spec's ``tissue = ["default"]`` stands for, in order.
DEFAULT_SETTING_NAMES = ("healthy", *DEFAULT_SCARS)


@dataclass(frozen=True)
class Material:
    """Aliev-Panfilov tissue parameters of one region.

    ``a`` is the excitability threshold, ``D`` a dimensionless scale of the base
    diffusivity (1 = healthy conduction, 0 = no diffusive coupling).
    """

    a: float = 0.15
    D: float = 1.0

    def __post_init__(self) -> None:
        if not np.isfinite(self.a) or not A_RANGE[0] <= self.a <= A_RANGE[1]:
            raise TissueError(f"excitability a={self.a} outside the admissible range {A_RANGE}")
        if not np.isfinite(self.D) or not D_RANGE[0] <= self.D <= D_RANGE[1]:
            raise TissueError(f"diffusivity scale D={self.D} outside the admissible range {D_RANGE}")


HEALTHY = Material()


@dataclass(frozen=True)
class ScarSpec:
    """One scar: a region with a core and an optional border zone.

    ``region = "segments"`` selects AHA segments (1-17) of the LV;
    ``region = "sphere"`` selects nodes within ``radius`` mm of ``centre``
    (coordinates) or of node ``node``. The border zone is the band of width
    ``border_width`` mm around the core.
    """

    region: Literal["segments", "sphere"]
    segments: tuple[int, ...] = ()
    centre: tuple[float, float, float] | None = None
    node: int | None = None
    radius: float = 0.0
    core: Material = field(default_factory=lambda: Material(a=0.5, D=0.1))
    border: Material = field(default_factory=lambda: Material(a=0.3, D=0.5))
    border_width: float = 0.0

    def __post_init__(self) -> None:
        if self.region not in ("segments", "sphere"):
            raise TissueError(f"unknown scar region {self.region!r} (use 'segments' or 'sphere')")
        if self.region == "segments":
            if not self.segments:
                raise TissueError("segment scar needs a non-empty list of AHA segments")
            bad = [s for s in self.segments if not 1 <= int(s) <= 17]
            if bad:
                raise TissueError(f"AHA segments must be in 1..17, got {bad}")
        else:
            if (self.centre is None) == (self.node is None):
                raise TissueError("sphere scar needs exactly one of 'centre' or 'node'")
            if not np.isfinite(self.radius) or self.radius <= 0:
                raise TissueError(f"sphere scar radius must be > 0 mm, got {self.radius}")
            if self.centre is not None and not np.all(np.isfinite(self.centre)):
                raise TissueError(f"sphere scar centre must be finite, got {self.centre}")
        if not np.isfinite(self.border_width) or self.border_width < 0:
            raise TissueError(f"border_width must be >= 0 mm, got {self.border_width}")


@dataclass(frozen=True)
class TissueSpec:
    """A named tissue setting: healthy material plus zero or more scars, and optionally its own ratio
    ``anisotropy = D_l / D_t`` of conduction along and across the mesh's fibres (``None``: the solver's)."""

    name: str = "healthy"
    healthy: Material = HEALTHY
    scars: tuple[ScarSpec, ...] = ()
    anisotropy: float | None = None

    def __post_init__(self) -> None:
        if self.anisotropy is not None and not (np.isfinite(self.anisotropy) and self.anisotropy >= 1):
            raise TissueError(f"tissue {self.name!r}: anisotropy must be a ratio D_l / D_t >= 1, got {self.anisotropy}")


@dataclass(frozen=True)
class TissueFields:
    """Per-node tissue fields on one mesh.

    ``a`` excitability, ``D`` diffusivity scale and ``label`` (0 healthy,
    1 border zone, 2 scar core), all of length N.
    """

    a: NDArray[np.float64]
    D: NDArray[np.float64]
    label: NDArray[np.int8]

    def __post_init__(self) -> None:
        n = len(self.a)
        if len(self.D) != n or len(self.label) != n:
            raise TissueError("tissue fields a, D and label must have the same length")
        if not (np.all(np.isfinite(self.a)) and np.all(np.isfinite(self.D))):
            raise TissueError("tissue fields contain NaN or infinite values")

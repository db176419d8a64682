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
from shared.units import MS_PER_TIME_UNIT

__all__ = [
    "Material",
    "ScarSpec",
    "FibrosisSpec",
    "TissueSpec",
    "SCAR_REGIONS",
    "TissueFields",
    "HEALTHY",
    "A_RANGE",
    "D_RANGE",
    "APD_SCALE_RANGE",
    "LABEL_HEALTHY",
    "LABEL_BORDER",
    "LABEL_CORE",
    "LABEL_FIBROSIS",
    "LABEL_NAMES",
    "DEFAULT_SCARS",
    "DEFAULT_SETTING_NAMES",
    "ABNORMAL_LABELS",
    "front_speed",
    "healthy_speed",
]

#: Admissible excitability ``a`` (healthy 0.15; 0.5 and above does not propagate).
A_RANGE = (0.05, 0.5)
#: Admissible diffusivity scale (multiplies the solver's base diffusivity; 4 conducts twice as fast as 1).
D_RANGE = (0.0, 4.0)
#: Admissible scale of the cell model's action-potential duration (:attr:`TissueSpec.apd_scale`).
APD_SCALE_RANGE = (0.5, 2.0)

LABEL_HEALTHY, LABEL_BORDER, LABEL_CORE, LABEL_FIBROSIS = 0, 1, 2, 3
#: What each tissue label stands for.
LABEL_NAMES = {
    LABEL_HEALTHY: "healthy",
    LABEL_BORDER: "border zone",
    LABEL_CORE: "scar core",
    LABEL_FIBROSIS: "fibrosis",
}

#: The labels of abnormal tissue, what a personalised heart's abnormal-tissue map estimates: scar core and border.
ABNORMAL_LABELS = (LABEL_BORDER, LABEL_CORE)

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


#: Where a scar's core lies (:class:`ScarSpec`).
SCAR_REGIONS = ("segments", "sphere", "wall")


@dataclass(frozen=True)
class ScarSpec:
    """One scar: a region with a core and an optional border zone.

    ``region = "segments"`` selects AHA segments (1-17) of the LV;
    ``region = "sphere"`` selects nodes within ``radius`` mm of ``centre``
    (coordinates) or of node ``node``; ``region = "wall"`` places an ellipsoid
    in the wall of a ventricle at a point given in the heart's own coordinates,
    so that one scar means the same place on every anatomy:

    - ``ventricle`` (``"lv"``, the default, or ``"rv"``), ``height`` (0 apex, 1 base) and
      ``angle`` (degrees about the long axis, AHA convention: 0 septum, +90
      anterior, -90 inferior, 180 lateral) fix the centre, the ventricle's endocardial
      node nearest that height and angle (the RV's free wall, for ``"rv"``);
    - ``radius`` (mm) is the ellipsoid's semi-axis across the wall and around the
      ventricle, ``radius * elongation`` its semi-axis along the long axis;
    - ``transmural`` (0-1, unset: 1) keeps the nodes whose transmural coordinate
      (0 endocardium, 1 epicardium) is at most it: a subendocardial scar below 1, a
      transmural one at 1 (volume meshes; a surface has no depth).

    ``optional`` (wall scars): a scar in a ventricle the mesh does not have (the RV
    of an LV) is left out instead of refused, so one drawn tissue serves LVs and
    biventricles. The border zone is the band of width ``border_width`` mm
    around the core.
    """

    region: Literal["segments", "sphere", "wall"]
    segments: tuple[int, ...] = ()
    centre: tuple[float, float, float] | None = None
    node: int | None = None
    radius: float = 0.0
    core: Material = field(default_factory=lambda: Material(a=0.5, D=0.1))
    border: Material = field(default_factory=lambda: Material(a=0.3, D=0.5))
    border_width: float = 0.0
    ventricle: Literal["lv", "rv"] | None = None
    height: float | None = None
    angle: float | None = None
    elongation: float | None = None
    transmural: float | None = None
    optional: bool | None = None

    def __post_init__(self) -> None:
        if self.region not in SCAR_REGIONS:
            raise TissueError(f"unknown scar region {self.region!r} (use one of {list(SCAR_REGIONS)})")
        wall_keys = ("ventricle", "height", "angle", "elongation", "transmural", "optional")
        given = [k for k in wall_keys if getattr(self, k) is not None]
        if given and self.region != "wall":
            raise TissueError(f"{given} apply to region = 'wall' scars, not to {self.region!r}")
        if self.region == "segments":
            if not self.segments:
                raise TissueError("segment scar needs a non-empty list of AHA segments")
            bad = [s for s in self.segments if not 1 <= int(s) <= 17]
            if bad:
                raise TissueError(f"AHA segments must be in 1..17, got {bad}")
        elif self.region == "sphere":
            if (self.centre is None) == (self.node is None):
                raise TissueError("sphere scar needs exactly one of 'centre' or 'node'")
            self._check_radius()
            if self.centre is not None and not np.all(np.isfinite(self.centre)):
                raise TissueError(f"sphere scar centre must be finite, got {self.centre}")
        else:
            self._check_wall()
        if not np.isfinite(self.border_width) or self.border_width < 0:
            raise TissueError(f"border_width must be >= 0 mm, got {self.border_width}")

    def _check_radius(self) -> None:
        if not np.isfinite(self.radius) or self.radius <= 0:
            raise TissueError(f"{self.region} scar radius must be > 0 mm, got {self.radius}")

    def _check_wall(self) -> None:
        if self.height is None or self.angle is None:
            raise TissueError("wall scar needs a height (0 apex .. 1 base) and an angle (degrees)")
        if self.ventricle not in (None, "lv", "rv"):
            raise TissueError(f"wall scar ventricle {self.ventricle!r} is not one of ['lv', 'rv']")
        if not (np.isfinite(self.height) and 0.0 <= self.height <= 1.0):
            raise TissueError(f"wall scar height must lie in [0, 1] (apex to base), got {self.height}")
        if not (np.isfinite(self.angle) and -180.0 <= self.angle <= 180.0):
            raise TissueError(f"wall scar angle must lie in [-180, 180] degrees, got {self.angle}")
        self._check_radius()
        if self.elongation is not None and not (np.isfinite(self.elongation) and self.elongation > 0):
            raise TissueError(f"wall scar elongation must be > 0, got {self.elongation}")
        if self.transmural is not None and not (np.isfinite(self.transmural) and 0 < self.transmural <= 1):
            raise TissueError(f"wall scar transmural extent must lie in (0, 1], got {self.transmural}")


@dataclass(frozen=True)
class FibrosisSpec:
    """Diffuse patchy fibrosis: patches of about ``patch`` mm, of which a share ``density`` (0-1) is fibrotic.

    The patches are the Voronoi cells of points of a jittered lattice of spacing ``patch`` mm anchored at the
    origin, each fibrotic with probability ``density`` (seeded by ``seed``), so the pattern lies in space,
    the same at every resolution of one mesh. Fibrotic nodes outside scars take ``material`` (label 3).
    """

    density: float
    patch: float
    seed: int = 0
    material: Material = field(default_factory=lambda: Material(a=0.3, D=0.2))

    def __post_init__(self) -> None:
        if not (np.isfinite(self.density) and 0.0 <= self.density <= 1.0):
            raise TissueError(f"fibrosis density must lie in [0, 1], got {self.density}")
        if not (np.isfinite(self.patch) and self.patch > 0):
            raise TissueError(f"fibrosis patch size must be > 0 mm, got {self.patch}")


@dataclass(frozen=True)
class TissueSpec:
    """A named tissue setting: healthy material plus zero or more scars and optional diffuse ``fibrosis``.

    Optionally its own ratio ``anisotropy = D_l / D_t`` of conduction along and across the mesh's fibres
    (``None``: the solver's), and ``apd_scale``, a factor on the cell model's action-potential duration
    (:data:`APD_SCALE_RANGE`; ``None``: 1, the model's own): Aliev-Panfilov's recovery rates ``eps0``, ``mu1``
    and ``eps_simple`` are divided by it, Mitchell-Schaeffer's ``tau_close`` multiplied.
    """

    name: str = "healthy"
    healthy: Material = HEALTHY
    scars: tuple[ScarSpec, ...] = ()
    anisotropy: float | None = None
    apd_scale: float | None = None
    fibrosis: FibrosisSpec | None = None

    def __post_init__(self) -> None:
        if self.anisotropy is not None and not (np.isfinite(self.anisotropy) and self.anisotropy >= 1):
            raise TissueError(f"tissue {self.name!r}: anisotropy must be a ratio D_l / D_t >= 1, got {self.anisotropy}")
        lo, hi = APD_SCALE_RANGE
        if self.apd_scale is not None and not (np.isfinite(self.apd_scale) and lo <= self.apd_scale <= hi):
            raise TissueError(
                f"tissue {self.name!r}: apd_scale {self.apd_scale} outside the admissible range {APD_SCALE_RANGE}"
            )
        if self.apd_scale == 1.0:  # the default written out: unset
            object.__setattr__(self, "apd_scale", None)


@dataclass(frozen=True)
class TissueFields:
    """Per-node tissue fields on one mesh.

    ``a`` excitability, ``D`` diffusivity scale and ``label`` (0 healthy,
    1 border zone, 2 scar core, 3 fibrosis: :data:`LABEL_NAMES`), all of length N.
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


def front_speed(D: float, a: float, k: float = 8.0) -> float:
    """Aliev-Panfilov's planar front speed (recovery neglected): ``sqrt(2kD)(1/2 - a)``, mesh units per time unit
    at diffusivity ``D``."""
    return float(np.sqrt(2.0 * k * D) * (0.5 - a))


def healthy_speed(tissue: TissueSpec, diffusivity: float, k: float = 8.0) -> float:
    """The conduction velocity (m/s, along fibres) of ``tissue``'s healthy material on mm meshes under a solver of
    base ``diffusivity`` (mm^2 per time unit) and Aliev-Panfilov's ``k``, from :func:`front_speed`.

    It is within 3 % of the speed measured on a strip (``simgen.tissue.tune``) for excitability 0.12-0.25, and
    what a learner can know without running the simulator."""
    return front_speed(diffusivity * tissue.healthy.D, tissue.healthy.a, k) / MS_PER_TIME_UNIT

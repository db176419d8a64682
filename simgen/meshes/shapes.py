"""Physiological shape parameters of the procedural LV and BiV, with their admissible ranges.

:class:`LVShape` and :class:`BiVShape` describe an anatomy in clinical terms
(lengths, radii and wall thicknesses in mm, angles in degrees); ``geometry()``
turns them into the :class:`~simgen.meshes.ellipsoid.LVGeometry` /
:class:`~simgen.meshes.biventricular.BiVGeometry` the mesh generators take.
Every ranged parameter is checked against its range (inclusive); the ranges
and their sources are in ``docs/anatomies.md``. The sampler draws from the
same range unless the parameter has a narrower default sampling interval
(the RV's size, which extends to dilated RVs). The defaults give the default
geometries (the BiV's RV breadth to within 0.1 mm, since it is set through a
wrap angle).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from shared.config import from_mapping
from shared.errors import MeshError
from simgen.meshes.biventricular import BiVGeometry
from simgen.meshes.ellipsoid import LVGeometry
from simgen.meshes.harmonics import random_coefficients

__all__ = ["BUMP_DEGREE", "LVShape", "BiVShape", "SHAPES", "Range", "parameter_ranges", "shape_from_params"]

#: Highest spherical-harmonic degree of the surface perturbation.
BUMP_DEGREE = 4

#: RV endocardial centre offset along x as a fraction of its x semi-axis (the default 18 / 36).
_RV_CENTRE_FRACTION = 0.5


@dataclass(frozen=True)
class Range:
    """Admissible interval of a shape parameter, and the interval it is sampled from by default.

    ``sampled`` is ``None`` when the sampler draws from the whole admissible range.
    """

    lo: float
    hi: float
    unit: str
    meaning: str
    sampled: tuple[float, float] | None = None

    @property
    def draw(self) -> tuple[float, float]:
        """The default sampling interval."""
        return self.sampled or (self.lo, self.hi)


def _ranged(
    default: float, lo: float, hi: float, unit: str, meaning: str, sampled: tuple[float, float] | None = None
) -> Any:
    """A dataclass field with its :class:`Range` in the metadata."""
    return field(default=default, metadata={"range": Range(lo, hi, unit, meaning, sampled)})


def parameter_ranges(cls: type[LVShape]) -> dict[str, Range]:
    """The ranged parameters of a shape class, in declaration order."""
    return {f.name: f.metadata["range"] for f in dataclasses.fields(cls) if "range" in f.metadata}


@dataclass(frozen=True)
class LVShape:
    """An LV in clinical terms (end-diastolic, adult); defaults give :class:`LVGeometry`'s defaults."""

    length: float = _ranged(80.0, 70.0, 100.0, "mm", "long axis, epicardial apex to base plane")
    endo_radius: float = _ranged(25.0, 20.0, 30.0, "mm", "endocardial short-axis radius (anterior-inferior)")
    wall_thickness: float = _ranged(10.0, 7.0, 14.0, "mm", "wall thickness at the equator")
    apex_thickness: float = _ranged(8.0, 5.0, 11.0, "mm", "wall thickness at the apex")
    base_height: float = _ranged(15.0, 5.0, 20.0, "mm", "base truncation: base plane above the equator")
    eccentricity_index: float = _ranged(
        1.0, 1.0, 1.25, "", "short-axis eccentricity index D2/D1 (D1 septal-lateral); > 1 flattens the septum"
    )
    apex_offset: float = _ranged(0.0, 0.0, 10.0, "mm", "sideways shift of the apex from the base-centre line")
    apex_offset_angle: float = _ranged(0.0, 0.0, 360.0, "deg", "direction of the apex shift, from +x towards +y")
    bump_amplitude: float = _ranged(0.0, 0.0, 3.0, "mm", "RMS of the smooth random surface perturbation")
    bump_seed: int = 0

    def __post_init__(self) -> None:
        family = type(self).__name__.removesuffix("Shape")
        for name, r in parameter_ranges(type(self)).items():
            value = getattr(self, name)
            if isinstance(value, bool) or not (isinstance(value, (int, float)) and r.lo <= value <= r.hi):
                unit = f" {r.unit}" if r.unit else ""
                raise MeshError(
                    f"{family} shape: {name} = {value!r}{unit} is outside the physiological range "
                    f"{r.lo:g}..{r.hi:g}{unit} ({r.meaning})"
                )
        if isinstance(self.bump_seed, bool) or not isinstance(self.bump_seed, int) or self.bump_seed < 0:
            raise MeshError(f"{family} shape: bump_seed must be an integer >= 0, got {self.bump_seed!r}")

    def params(self) -> dict[str, float | int]:
        """Every parameter by name (JSON-able; :func:`shape_from_params` inverts it)."""
        return dataclasses.asdict(self)

    def geometry(self) -> LVGeometry:
        """The LV geometry these parameters describe."""
        epi_long = self.length - self.base_height
        angle = np.radians(self.apex_offset_angle)
        return LVGeometry(
            endo_short=self.endo_radius,
            endo_long=epi_long - self.apex_thickness,
            epi_short=self.endo_radius + self.wall_thickness,
            epi_long=epi_long,
            base_z=self.base_height,
            eccentricity_index=self.eccentricity_index,
            apex_offset=(self.apex_offset * float(np.cos(angle)), self.apex_offset * float(np.sin(angle))),
            bumps=random_coefficients(self.bump_amplitude, self.bump_seed, BUMP_DEGREE),
        )


@dataclass(frozen=True)
class BiVShape(LVShape):
    """An LV plus an RV on its +x (septal) side; defaults give :class:`BiVGeometry`'s defaults."""

    # The RV's size extends to dilated RVs (e.g. repaired tetralogy of Fallot); by default the
    # sampler keeps to typical adult RVs, and a spec's shape_ranges can draw dilated ones.
    rv_width: float = _ranged(
        19.0, 14.0, 36.0, "mm", "RV cavity width beyond the LV epicardium at the equator", (14.0, 28.0)
    )
    rv_wrap_angle: float = _ranged(
        168.0, 120.0, 200.0, "deg", "arc of the LV between the RV insertion points at the equator", (120.0, 190.0)
    )
    rv_length: float = _ranged(
        0.8125, 0.7, 0.9, "", "depth of the RV cavity below the base plane / length", (0.7, 0.85)
    )
    rv_wall_thickness: float = _ranged(5.0, 3.0, 6.0, "mm", "RV free-wall thickness")

    def geometry(self) -> BiVGeometry:
        """The BiV geometry: RV endocardial ellipsoid centred on the x axis, uniform free wall.

        Its x semi-axis gives the cavity width, its z semi-axis the depth
        (centre at z = 0) and its y semi-axis passes through the insertion
        points, at polar angles +-wrap/2 on the LV epicardial equator.
        """
        lv = super().geometry()
        epi_x, epi_y, _ = lv.radii(1)
        a_x = (self.rv_width + epi_x) / (1.0 + _RV_CENTRE_FRACTION)
        centre = _RV_CENTRE_FRACTION * a_x
        half = np.radians(self.rv_wrap_angle / 2)
        rho = 1.0 / np.hypot(np.cos(half) / epi_x, np.sin(half) / epi_y)  # LV epicardial equator at that angle
        # Within the ranges |rho cos(half) - centre| < 0.72 a_x, so the root is real.
        a_y = float(rho * np.sin(half) / np.sqrt(1.0 - ((rho * np.cos(half) - centre) / a_x) ** 2))
        a_z = self.rv_length * self.length - self.base_height
        endo = (a_x, a_y, a_z)
        return BiVGeometry(
            lv=lv,
            rv_centre=(centre, 0.0, 0.0),
            rv_endo_axes=endo,
            rv_epi_axes=tuple(a + self.rv_wall_thickness for a in endo),
        )


#: Shape class of each procedural family.
SHAPES: dict[str, type[LVShape]] = {"lv": LVShape, "biv": BiVShape}


def shape_from_params(family: str, params: dict[str, Any]) -> LVShape:
    """The shape of ``family`` (``"lv"``, ``"biv"``) from a parameter table; missing ones take defaults.

    Unknown names and wrong types raise :class:`~shared.errors.ConfigError`,
    values outside their range :class:`MeshError`.
    """
    if family not in SHAPES:
        raise MeshError(f"shape parameters need a procedural source {sorted(SHAPES)}, got {family!r}")
    return from_mapping(SHAPES[family], params, where="shape_params")

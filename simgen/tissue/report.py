"""Tissue settings described for people: one row of physical and drawn parameters per setting, and a picture.

:func:`tissue_rows` is what ``simgen tissues`` prints: for every setting its healthy
tissue in physical terms (conduction velocity in m/s, along and across fibres
where it has an anisotropy, and APD90 in ms: :func:`simgen.tissue.tune.physical`)
beside the parameters that give them, its scars and its fibrosis.
:func:`plot_tissue_draws` draws a few settings' labels on one mesh.
"""

from __future__ import annotations

from collections.abc import Sequence
from os import PathLike

import numpy as np

from shared.mesh import Mesh
from shared.tissue import FibrosisSpec, ScarSpec, TissueSpec
from simgen.solver.simulate import SolverConfig
from simgen.tissue.fields import tissue_fields
from simgen.tissue.tune import physical

__all__ = [
    "TISSUE_COLUMNS",
    "SPEED_BAND",
    "tissue_family",
    "scar_summary",
    "fibrosis_summary",
    "tissue_rows",
    "plot_tissue_draws",
    "scar_location",
]

#: The columns of :func:`tissue_rows`, in order.
TISSUE_COLUMNS = ("name", "family", "a", "D", "CV (m/s)", "APD90 (ms)", "scars", "border (mm)", "fibrosis")

#: Relative band around the default tissue's conduction velocity inside which healthy tissue is "normal".
SPEED_BAND = 0.1


def tissue_family(spec: TissueSpec, solver: SolverConfig | None = None) -> str:
    """The family a setting belongs to, for results per family: ``"fibrosis"`` (patchy fibrosis, with or
    without scars), ``"several scars"``, ``"one scar"``, else by its healthy conduction velocity against the
    default tissue's under ``solver``: ``"slower"`` or ``"faster"`` beyond :data:`SPEED_BAND`, or ``"normal"``."""
    if spec.fibrosis is not None:
        return "fibrosis"
    if spec.scars:
        return "several scars" if len(spec.scars) > 1 else "one scar"
    solver = solver or SolverConfig()
    ratio = physical(spec, solver).cv / physical(TissueSpec(), solver).cv
    return "slower" if ratio < 1 - SPEED_BAND else "faster" if ratio > 1 + SPEED_BAND else "normal"


def scar_summary(scar: ScarSpec) -> str:
    """One scar in a few words: its AHA segments, its sphere, or its wall ellipsoid (ventricle, height,
    angle, radius, elongation and transmural extent)."""
    if scar.region == "segments":
        return "AHA " + ",".join(map(str, scar.segments))
    if scar.region == "sphere":
        where = f"node {scar.node}" if scar.node is not None else "point"
        return f"ball r {scar.radius:g} mm at {where}"
    shape = f"r {scar.radius:.0f} mm x{scar.elongation or 1:.1f}"
    depth = f", {100 * (scar.transmural or 1):.0f}% deep"
    return f"{(scar.ventricle or 'lv').upper()} h {scar.height:.2f} {scar.angle:+.0f}deg {shape}{depth}"


def scar_location(scar: ScarSpec) -> str:
    """Where a scar lies, in a clinician's words: ``"LV anterior mid"``, ``"RV free wall basal"``, or its AHA
    segments. Heights split apical / mid / basal at thirds; angles name the sector around the LV (AHA: 0
    septum, +90 anterior, -90 inferior, 180 lateral)."""
    if scar.region != "wall":
        return scar_summary(scar)
    level = "apical" if scar.height < 1 / 3 else "mid" if scar.height < 2 / 3 else "basal"
    if (scar.ventricle or "lv") == "rv":
        return f"RV free wall {level}"
    turn = (scar.angle + 180.0) % 360.0 - 180.0
    sector = "septal" if abs(turn) <= 45 else "lateral" if abs(turn) >= 135 else "anterior" if turn > 0 else "inferior"
    return f"LV {sector} {level}"


def fibrosis_summary(fibrosis: FibrosisSpec) -> str:
    """``"12% of 4.2 mm patches"``."""
    return f"{100 * fibrosis.density:.0f}% of {fibrosis.patch:.1f} mm patches"


def tissue_rows(settings: Sequence[TissueSpec], solver: SolverConfig | None = None) -> list[dict[str, str]]:
    """One row per setting under ``solver`` (unset: the defaults), keyed by :data:`TISSUE_COLUMNS`."""
    solver = solver or SolverConfig()
    rows = []
    for spec in settings:
        found = physical(spec, solver)
        cv = f"{found.cv:.2f}" if found.cv_across is None else f"{found.cv:.2f} / {found.cv_across:.2f}"
        rows.append(
            {
                "name": spec.name,
                "family": tissue_family(spec, solver),
                "a": f"{spec.healthy.a:.3g}",
                "D": f"{spec.healthy.D:.3g}",
                "CV (m/s)": cv,
                "APD90 (ms)": f"{found.apd:.0f}",
                "scars": "; ".join(map(scar_summary, spec.scars)) or "-",
                "border (mm)": "; ".join(f"{s.border_width:.1f}" for s in spec.scars) or "-",
                "fibrosis": "-" if spec.fibrosis is None else fibrosis_summary(spec.fibrosis),
            }
        )
    return rows


def plot_tissue_draws(mesh: Mesh, settings: Sequence[TissueSpec], path: str | PathLike[str]) -> None:
    """The labels of ``settings`` on ``mesh`` (healthy, border zone, scar core, fibrosis), one row each, as a PNG."""
    from simgen.plot import plot_tissues  # matplotlib: only for a picture

    labels = np.stack([tissue_fields(mesh, spec).label for spec in settings])
    plot_tissues(mesh, labels, [f"{mesh.name}: {spec.name}" for spec in settings], path)

"""Stimulation sites by position: node ids, coordinates in mm, or named anatomical regions.

A site given as coordinates is the node nearest the point, refused when that
node lies farther than a tolerance (:data:`SITE_TOLERANCE`, mm). A site given
as a region is the node of the region's surface nearest the centre of that
surface patch:

- ``aha-1`` ... ``aha-17``: the AHA segments of the left ventricle (17 is the
  apical cap), ``apex`` the same as ``aha-17``; where the cap has no node on
  the surface asked for (the endocardium of a cap beyond the cavity's tip),
  the surface's node nearest the cap;
- ``rv-free-wall``: the right ventricle's free wall (biventricular meshes);
- a suffix ``:epi`` (the default) or ``:endo`` picks the epicardial or the
  endocardial surface of the region.

Regions need per-node labels (:class:`SiteLabels`): simgen computes them from
a heart's node sets and long axis (:func:`simgen.meshes.regions.site_labels`)
and writes them beside the mesh (mesh files of ``simgen mesh``, observation
files of ``simgen simulate --observe``), where the learner reads them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from shared.errors import StimulusError

__all__ = [
    "SITE_TOLERANCE",
    "REGIONS",
    "SURFACES",
    "SiteLabels",
    "parse_points",
    "refuse_repeated",
    "site_names",
    "parse_regions",
    "nearest_nodes",
    "region_nodes",
]

#: Largest distance (mm) from a point to the node that stands for it as a site.
SITE_TOLERANCE = 5.0

#: Region names of :func:`region_nodes`.
REGIONS = (*(f"aha-{k}" for k in range(1, 18)), "apex", "rv-free-wall")

#: Surfaces a region's site may lie on; the first is the default.
SURFACES = ("epi", "endo")


@dataclass(frozen=True)
class SiteLabels:
    """Per-node anatomical labels of a heart mesh, what :func:`region_nodes` needs.

    Parameters
    ----------
    segment : (N,) int8, the AHA segment (1-17) of left-ventricular nodes, 0 elsewhere.
    epicardium, endocardium : (N,) bool, the two surfaces.
    rv_free_wall : (N,) bool, the right ventricle's free wall (all false for an LV alone).
    """

    segment: NDArray[np.int8]
    epicardium: NDArray[np.bool_]
    endocardium: NDArray[np.bool_]
    rv_free_wall: NDArray[np.bool_]

    #: The arrays' names as point data of mesh files and as arrays of observation files.
    NAMES = ("aha_segment", "epicardium", "endocardium", "rv_free_wall")

    def __post_init__(self) -> None:
        n = len(self.segment)
        for name in ("epicardium", "endocardium", "rv_free_wall"):
            if np.shape(getattr(self, name)) != (n,):
                raise StimulusError(f"site labels: {name} must have {n} entries like aha_segment")

    @property
    def n_nodes(self) -> int:
        return len(self.segment)

    def arrays(self) -> dict[str, NDArray]:
        """The labels as arrays named :attr:`NAMES` (0/1 uint8 for the masks)."""
        masks = (self.epicardium, self.endocardium, self.rv_free_wall)
        return dict(zip(self.NAMES, (self.segment.astype(np.int8), *(m.astype(np.uint8) for m in masks))))

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, ArrayLike]) -> SiteLabels | None:
        """Labels from arrays named :attr:`NAMES` (point data, an ``.npz``); ``None`` when any is missing."""
        if not all(name in arrays for name in cls.NAMES):
            return None
        segment, *masks = (np.asarray(arrays[name]).reshape(-1) for name in cls.NAMES)
        if not (np.isin(segment, np.arange(18)).all() and all(np.isin(m, (0, 1)).all() for m in masks)):
            raise StimulusError(f"site labels: {cls.NAMES[0]} must hold 0-17 and the masks 0/1")
        for name, mask in zip(cls.NAMES[1:], masks):
            share = "every" if mask.all() else "no" if not mask.any() and name != "rv_free_wall" else None
            if share:
                raise StimulusError(
                    f"site labels: {name} marks {share} node of the {len(mask)}: a surface of the heart holds some "
                    "nodes and not all (a mask of another mesh, or inverted?); write the labels with `simgen mesh`"
                )
        return cls(segment.astype(np.int8), *(m.astype(bool) for m in masks))


def refuse_repeated(nodes: ArrayLike, given: Sequence[str]) -> None:
    """Refuse sites that name one node twice, by id, point or region alike; ``given[i]`` says how site ``i``
    was named (``"node 3"``, ``"point (1, 2, 3)"``, ``"region aha-1"``)."""
    by_node: dict[int, list[str]] = {}
    for node, name in zip(np.asarray(nodes).reshape(-1).tolist(), given):
        by_node.setdefault(int(node), []).append(name)
    for node, names in by_node.items():
        if len(names) > 1:
            raise StimulusError(
                f"sites {' and '.join(names)} are one stimulation node ({node}): it would be paced twice; "
                "give each site once"
            )


def site_names(ids: ArrayLike, points: ArrayLike | None, regions: Sequence[str]) -> list[str]:
    """How each site of ``ids``, then ``points`` (K, 3) mm, then ``regions`` was named, for :func:`refuse_repeated`."""
    named = [f"node {int(i)}" for i in np.asarray(ids).reshape(-1)]
    if points is not None:
        named += ["point (" + ", ".join(f"{v:g}" for v in p) + ")" for p in np.asarray(points, float).reshape(-1, 3)]
    return named + [f"region {r}" for r in regions]


def parse_points(text: str, option: str = "--site-xyz") -> NDArray[np.float64]:
    """``"x,y,z;x,y,z"`` (mm) as a ``(K, 3)`` array; :class:`StimulusError` naming ``option`` otherwise."""
    points = []
    for item in filter(None, (part.strip() for part in text.split(";"))):
        try:
            xyz = [float(v) for v in item.split(",")]
        except ValueError:
            xyz = []
        if len(xyz) != 3 or not np.isfinite(xyz).all():
            raise StimulusError(f"{option}: {item!r} is not a point x,y,z in mm (points are separated by ';')")
        points.append(xyz)
    if not points:
        raise StimulusError(f"{option}: give at least one point x,y,z in mm")
    return np.asarray(points, np.float64)


def parse_regions(text: str, option: str = "--site-region") -> list[str]:
    """``"aha-5,apex:endo"`` as the list of region names, each checked (:func:`region_nodes` resolves them)."""
    names = [part.strip() for part in text.split(",") if part.strip()]
    if not names:
        raise StimulusError(f"{option}: give at least one region")
    for name in names:
        _split_region(name, option)
    return names


def _split_region(name: str, option: str = "region") -> tuple[str, str]:
    region, _, surface = name.partition(":")
    surface = surface or SURFACES[0]
    if region not in REGIONS or surface not in SURFACES:
        raise StimulusError(
            f"{option}: unknown region {name!r}; use aha-1 ... aha-17, apex or rv-free-wall, optionally with "
            f":{' or :'.join(SURFACES)}"
        )
    return region, surface


def nearest_nodes(
    points: ArrayLike,
    xyz: ArrayLike,
    tolerance: float = SITE_TOLERANCE,
    candidates: ArrayLike | None = None,
    what: str = "node",
) -> NDArray[np.int64]:
    """The node nearest each point of ``xyz`` (K, 3) among ``points`` (N, 3), or among node ids
    ``candidates`` (``what`` names them in errors); :class:`StimulusError` naming the point and its
    distance when the nearest lies farther than ``tolerance`` mm."""
    points, xyz = np.asarray(points, np.float64), np.atleast_2d(np.asarray(xyz, np.float64))
    pool = np.arange(len(points)) if candidates is None else np.asarray(candidates, np.int64)
    if xyz.shape[1:] != (3,) or not np.isfinite(xyz).all():
        raise StimulusError(f"site coordinates must be finite points (K, 3) in mm, got shape {xyz.shape}")
    distance = np.linalg.norm(points[pool][None, :, :] - xyz[:, None, :], axis=2)
    nearest = distance.argmin(axis=1)
    gap = distance[np.arange(len(xyz)), nearest]
    far = np.flatnonzero(gap > tolerance)
    if far.size:
        k = int(far[0])
        raise StimulusError(
            f"no {what} within {tolerance:g} mm of site point {np.round(xyz[k], 2).tolist()}: the nearest lies "
            f"{gap[k]:.1f} mm away; give a point on the mesh (coordinates in mm) or a larger tolerance"
        )
    return pool[nearest]


def region_nodes(labels: SiteLabels | None, points: ArrayLike, regions: Sequence[str]) -> NDArray[np.int64]:
    """One site per name of ``regions`` (module docstring): the node of the region's surface nearest the
    centre of that patch. :class:`StimulusError` when the mesh has no labels or a region no node."""
    if labels is None:
        raise StimulusError(
            "sites by region need the mesh's region labels (aha_segment, epicardium, endocardium, rv_free_wall): "
            "write the mesh with `simgen mesh FILE OUT.vtu` (node ids kept) and give that file"
        )
    points = np.asarray(points, np.float64)
    sites = []
    for name in regions:
        region, surface = _split_region(name)
        on = labels.epicardium if surface == "epi" else labels.endocardium
        if region == "rv-free-wall":
            inside = labels.rv_free_wall
        else:
            inside = labels.segment == (17 if region == "apex" else int(region.removeprefix("aha-")))
        patch = np.flatnonzero(inside & on)
        if not patch.size and region in ("apex", "aha-17") and inside.any() and on.any():
            patch = np.flatnonzero(on)  # a cap beyond the cavity's tip: the surface's node nearest the cap
            centre = points[inside].mean(axis=0)
        elif not inside.any():
            raise StimulusError(f"region {name!r} holds no node of this mesh (a left ventricle has no rv-free-wall)")
        elif not patch.size:
            other = SURFACES[1 - SURFACES.index(surface)]
            raise StimulusError(
                f"region {name!r} has no {surface}cardial node on this mesh (in a biventricle the septal segments "
                f"2, 3, 8, 9 and 14 face the cavities, not the epicardium): name '{region}:{other}'"
            )
        else:
            centre = points[patch].mean(axis=0)
        sites.append(int(patch[np.argmin(np.linalg.norm(points[patch] - centre, axis=1))]))
    return np.asarray(sites, np.int64)

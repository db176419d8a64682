"""AHA 17-segment labelling of ventricular meshes.

Every node gets a segment from its position in the ventricular frame
(:class:`shared.mesh.LongAxis`; estimated by PCA when the mesh has none).

Longitudinal coordinate, from apex (0) to base plane (1)::

    l = (x - apex) . d / |base - apex|,   d = (base - apex) / |base - apex|

* ``l < APEX_CAP`` (0.1): segment 17, the apical cap (for the default LV
  ellipsoid this is the tissue beyond the endocardial apex);
* ``l < 1/3``: apical ring, 4 segments 13-16;
* ``1/3 <= l < 2/3``: mid ring, 6 segments 7-12;
* ``l >= 2/3``: basal ring, 6 segments 1-6; nodes beyond the base plane
  (``l > 1``) count as basal and nodes beyond the apex (``l < 0``) as apex.

Circumferential angle about ``d``, from the reference direction ``r``::

    theta = atan2((d x r) . x_perp, r . x_perp)   in (-180, 180] degrees

so 0 deg is the septum (``r`` points towards the septum/RV), +90 deg anterior,
-90 deg inferior and 180 deg lateral. This is the bull's-eye seen from the
apex (anterior up, septum left), and matches anatomy: with ``d`` apex -> base
and ``r`` towards the RV, ``d x r`` points to the anterior wall.

Sectors (centre angles in degrees)::

    basal 1-6, mid 7-12   anterior 90, anteroseptal 30, inferoseptal -30,
                          inferior -90, inferolateral -150, anterolateral 150
    apical 13-16          anterior 90, septal 0, inferior -90, lateral 180
    apex 17               the cap l < APEX_CAP

Segments are defined for the LV; nodes of a BiV right-ventricular free wall
simply get the segment of their height and angle (they lie at theta ~ 0, so
they fall in the septal sectors).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from shared.errors import MeshError
from shared.mesh import LongAxis, Mesh

__all__ = ["APEX_CAP", "SEGMENT_NAMES", "estimate_axis", "longitudinal_angular", "aha_segments"]

#: Longitudinal coordinate below which nodes belong to the apical cap (segment 17).
APEX_CAP = 0.1

#: Conventional names of the 17 AHA segments.
SEGMENT_NAMES: dict[int, str] = {
    1: "basal anterior",
    2: "basal anteroseptal",
    3: "basal inferoseptal",
    4: "basal inferior",
    5: "basal inferolateral",
    6: "basal anterolateral",
    7: "mid anterior",
    8: "mid anteroseptal",
    9: "mid inferoseptal",
    10: "mid inferior",
    11: "mid inferolateral",
    12: "mid anterolateral",
    13: "apical anterior",
    14: "apical septal",
    15: "apical inferior",
    16: "apical lateral",
    17: "apex",
}

# Fraction of the extent along the axis whose nodes decide which end is the apex.
_END_BAND = 0.1


def estimate_axis(mesh: Mesh) -> LongAxis:
    """Long axis of a mesh without one, by principal component analysis.

    The axis is the direction of largest variance of the node positions through
    their centroid. The apex is the end whose nodes (within 10% of the extent
    from the extreme) have the smaller mean radius about the axis; ``apex`` and
    ``base`` are the extreme projections of the nodes onto the axis line.
    ``reference`` is the x unit vector made orthogonal to the axis, or the
    y unit vector when the axis is within 45 degrees of x (deterministic and
    stable for axis-aligned meshes, but not anatomical).
    """
    pts = mesh.points
    if len(pts) < 4:
        raise MeshError(f"mesh {mesh.name!r}: too few nodes to estimate a long axis")
    centroid = pts.mean(axis=0)
    x = pts - centroid
    _, vecs = np.linalg.eigh(x.T @ x)
    d = vecs[:, -1]
    s = x @ d
    radius = np.linalg.norm(x - s[:, None] * d, axis=1)
    lo, hi = s.min(), s.max()
    band = _END_BAND * (hi - lo)
    r_lo = radius[s <= lo + band].mean()
    r_hi = radius[s >= hi - band].mean()
    if r_hi < r_lo:
        d, s, lo, hi = -d, -s, -hi, -lo
    e = np.eye(3)[0 if abs(d[0]) < np.sqrt(0.5) else 1]
    ref = e - (e @ d) * d
    return LongAxis(apex=centroid + lo * d, base=centroid + hi * d, reference=ref / np.linalg.norm(ref))


def longitudinal_angular(mesh: Mesh) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Longitudinal coordinate ``l`` (0 apex, 1 base) and angle ``theta`` (degrees) per node.

    Uses ``mesh.axis`` or :func:`estimate_axis`; see the module docstring for
    the convention.
    """
    axis = mesh.axis if mesh.axis is not None else estimate_axis(mesh)
    d = axis.direction
    r = np.asarray(axis.reference, dtype=np.float64)
    r = r - (r @ d) * d  # tolerate a slightly non-orthogonal reference
    norm = np.linalg.norm(r)
    if not np.isfinite(norm) or norm < 1e-9:
        raise MeshError(f"mesh {mesh.name!r}: axis reference is parallel to the long axis")
    r /= norm
    x = mesh.points - np.asarray(axis.apex, dtype=np.float64)
    l = (x @ d) / axis.length
    theta = np.degrees(np.arctan2(x @ np.cross(d, r), x @ r))
    return l, theta


def aha_segments(mesh: Mesh, apex_cap: float = APEX_CAP) -> NDArray[np.int8]:
    """AHA segment (1-17) of every node, shape (N,), int8.

    Parameters
    ----------
    mesh : any ventricular mesh; ``mesh.axis`` is estimated when missing.
    apex_cap : longitudinal coordinate below which nodes form segment 17.
    """
    if not 0.0 <= apex_cap < 1.0 / 3.0:
        raise MeshError(f"apex_cap={apex_cap} must lie in [0, 1/3)")
    l, theta = longitudinal_angular(mesh)
    six = np.floor((120.0 - theta) / 60.0).astype(np.int64) % 6  # 0 = anterior
    four = np.floor((135.0 - theta) / 90.0).astype(np.int64) % 4
    seg = np.where(l >= 2.0 / 3.0, 1 + six, np.where(l >= 1.0 / 3.0, 7 + six, 13 + four))
    seg[l < apex_cap] = 17
    return seg.astype(np.int8)

"""What the physics of each recording allows: a recording in the wrong units, scale or order is refused.

Each check raises :class:`~shared.errors.InputError` with one line naming the
array and the likely mistake; :func:`unmapped_holes` finds what a warning names.

- potentials in mV: finite, within :data:`~shared.units.MV_RANGE` and
  reaching below :data:`REST_ABOVE_MV` (``u`` given as millivolts never does);
- frame times: a recording longer than :data:`SPAN_FACTOR` model windows has
  its times in ms given as model time units (a recording in ms up to that
  long is read, its frames past the window left out);
- activation maps: times spread over at least :data:`MIN_MAP_SPREAD_MS` (all
  zero, or seconds, otherwise), and each map mostly within the model's window;
- ECGs: no recording zero in every lead, and the limb leads keep Einthoven's
  I + III = II and Goldberger's aVR + aVL + aVF = 0 up to the recording's own
  noise (estimated from its frame-to-frame differences);
- electrodes: within :data:`ELECTRODES_FAR` heart sizes of the heart's centre,
  and spread over at least :data:`ELECTRODES_SPREAD` of its size;
- a mesh's points: a heart's size in mm (:data:`~shared.mesh.PLAUSIBLE_HEART_MM`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from shared.ecg import LEADS
from shared.errors import InputError
from shared.mesh import PLAUSIBLE_HEART_MM, Mesh
from shared.topology import boundary_faces
from shared.units import MS_PER_TIME_UNIT, MV_RANGE

__all__ = [
    "SPAN_FACTOR",
    "MIN_MAP_SPREAD_MS",
    "ELECTRODES_FAR",
    "ELECTRODES_SPREAD",
    "REST_ABOVE_MV",
    "check_millivolts",
    "check_frame_span",
    "check_map_spread",
    "check_map_window",
    "check_ecg",
    "check_electrodes",
    "check_points_scale",
    "unmapped_holes",
]

#: Recordings in mV whose lowest value is above this never come near rest (-80 mV): ``u`` given as mV.
REST_ABOVE_MV = -50.0
#: A recording spanning more than this many model windows: frame times in ms given as model time units (which
#: stretches a recording of the window about 12.9 times); a recording of one paced beat is far shorter.
SPAN_FACTOR = 8.0
#: Activation times spread over less than this (ms) across a map: all zero, or seconds.
MIN_MAP_SPREAD_MS = 1.0
#: Electrodes farther than this many heart sizes from the heart's centre: positions in another unit.
ELECTRODES_FAR = 20.0
#: Electrodes spread over less than this share of the heart's size: all at one point.
ELECTRODES_SPREAD = 0.25
#: Smallest unmapped patch :func:`unmapped_holes` names: this many nodes, and this share of the map (a few nodes
#: left out of a node set are no scar).
MIN_HOLE_NODES, MIN_HOLE_SHARE = 3, 0.01
#: A lead relation's residual allowed beyond the noise: this share of the limb leads' RMS.
LEAD_RESIDUAL = 0.1


def check_millivolts(mv: NDArray, name: str, alternative: str) -> None:
    """Refuse transmembrane potentials ``mv`` (any shape) that are not finite mV near rest and peak (``u`` given
    as mV); ``name`` and ``alternative`` (where ``u`` goes instead) name them in the one line."""
    if mv.size and (
        not np.isfinite(mv).all() or mv.min() < MV_RANGE[0] or mv.max() > MV_RANGE[1] or mv.min() > REST_ABOVE_MV
    ):
        raise InputError(
            f"{name} ranges from {np.min(mv):.4g} to {np.max(mv):.4g} (NaN or inf, or outside [{MV_RANGE[0]:g}, "
            f"{MV_RANGE[1]:g}] mV, or never near rest): give the transmembrane potential in mV (rest -80, peak "
            f"about 20){alternative}"
        )


def check_frame_span(times: NDArray, window: NDArray) -> None:
    """Refuse frame ``times`` (model time units) spanning more than :data:`SPAN_FACTOR` times the model's
    frame ``window``: milliseconds given as model time units."""
    span, model = float(times[-1] - times[0]), float(window[-1] - window[0])
    if model > 0 and span > SPAN_FACTOR * model:
        raise InputError(
            f"times: the recordings span {span:.4g} model time units, {span / model:.0f}x the model's window of "
            f"{model:.4g} ({model * MS_PER_TIME_UNIT:.0f} ms): times in ms given as model time units "
            f"({MS_PER_TIME_UNIT:g} ms each)? give milliseconds as times_ms, and one paced beat from its stimulus"
        )


def check_map_spread(activation_ms: NDArray, observed: NDArray) -> None:
    """Refuse activation maps (K, N) in ms whose finite times at the ``observed`` nodes spread over less than
    :data:`MIN_MAP_SPREAD_MS`: all zero, or given in seconds."""
    seen = activation_ms[:, observed]
    finite = seen[np.isfinite(seen)]
    if not finite.size:
        raise InputError("activation_ms: no mapped node activates (every time is inf): no activation to read")
    spread = float(finite.max() - finite.min())
    if spread < MIN_MAP_SPREAD_MS:
        raise InputError(
            f"activation_ms: the maps' times spread over {spread:.3g} ms at {int(observed.sum())} mapped nodes "
            f"(from {finite.min():.3g} to {finite.max():.3g}): all zero, or seconds? give ms after the stimulus"
        )


def check_map_window(activation: NDArray, observed: NDArray, window: NDArray) -> None:
    """Refuse an activation map (model time units) whose median finite time at the ``observed`` nodes lies
    after the model's frame ``window``: a map of another window, or times not counted from the stimulus."""
    end = float(window[-1])
    for k, row in enumerate(activation[:, observed]):
        finite = row[np.isfinite(row)]
        if finite.size and float(np.median(finite)) > end:
            raise InputError(
                f"activation_ms: map {k} activates at {np.median(finite) * MS_PER_TIME_UNIT:.0f} ms (median), after "
                f"the model's window of {window[0] * MS_PER_TIME_UNIT:.0f}-{end * MS_PER_TIME_UNIT:.0f} ms after the "
                "stimulus: give times counted from the stimulus onset"
            )


def _noise(ecg: NDArray) -> NDArray:
    """Per-recording noise std (K,) of ECGs (K, 12, T): the median absolute frame-to-frame difference."""
    diff = np.abs(np.diff(ecg, axis=-1))
    return np.median(diff.reshape(len(ecg), -1), axis=1) / (0.6745 * np.sqrt(2.0))


def check_ecg(ecg: NDArray) -> None:
    """Refuse ECGs (K, 12, T) in mV, leads in :data:`~shared.ecg.LEADS` order, zero in every lead, or whose limb
    leads break Einthoven's or Goldberger's relation beyond their noise (leads mislabelled or reordered)."""
    lead = {name: ecg[:, i] for i, name in enumerate(LEADS)}
    for k in np.flatnonzero(np.abs(ecg).reshape(len(ecg), -1).max(axis=1) == 0):
        raise InputError(f"ecg: recording {k} is zero in every lead: no ECG was recorded")
    limb = np.sqrt(np.mean(ecg[:, :6] ** 2, axis=(1, 2)))
    allowed = 3.0 * np.sqrt(3.0) * _noise(ecg) + LEAD_RESIDUAL * limb
    relations = {
        "I + III = II (Einthoven)": lead["I"] + lead["III"] - lead["II"],
        "aVR + aVL + aVF = 0 (Goldberger)": lead["aVR"] + lead["aVL"] + lead["aVF"],
    }
    for relation, residual in relations.items():
        rms = np.sqrt(np.mean(residual**2, axis=1))
        bad = np.flatnonzero(rms > allowed)
        if bad.size:
            k = int(bad[0])
            raise InputError(
                f"ecg: recording {k} breaks {relation} by {rms[k]:.3g} mV RMS (its limb leads: {limb[k]:.3g} mV): "
                f"leads mislabelled or out of order? give them in the order {list(LEADS)} or name them in leads"
            )


def check_electrodes(positions: NDArray, names: tuple[str, ...], mesh: Mesh) -> None:
    """Refuse ECG electrode ``positions`` (E, 3) in mm that lie more than :data:`ELECTRODES_FAR` heart sizes from
    the heart's centre, or all within :data:`ELECTRODES_SPREAD` of its size of each other."""
    centre, size = mesh.points.mean(axis=0), float(np.ptp(mesh.points, axis=0).max())
    far = np.linalg.norm(positions - centre, axis=1)
    k = int(np.argmax(far))
    if far[k] > ELECTRODES_FAR * size:
        raise InputError(
            f"electrode_xyz_mm: electrode {names[k]} lies {far[k]:.4g} mm from the heart's centre, "
            f"{far[k] / size:.0f}x the heart's {size:.0f} mm: positions in another unit than the mesh's (mm)?"
        )
    spread = float(np.ptp(positions, axis=0).max())
    if spread < ELECTRODES_SPREAD * size:
        raise InputError(
            f"electrode_xyz_mm: the {len(names)} electrodes lie within {spread:.3g} mm of each other, and the heart is "
            f"{size:.0f} mm across: all at one point? give each electrode's own position in mm"
        )


def check_points_scale(points: NDArray, name: str) -> None:
    """Refuse mesh ``points`` (N, 3) whose bounding box no heart in mm has (another length unit)."""
    extent = float(np.ptp(points, axis=0).max())
    lo, hi = PLAUSIBLE_HEART_MM
    if not lo <= extent <= hi:
        raise InputError(
            f"{name}: the points span {extent:.4g} across, and a heart spans {lo:g}-{hi:g} mm: points in another "
            "unit (m, or scaled)? give them in mm"
        )


def _surface_edges(mesh: Mesh) -> NDArray[np.int64]:
    """The edges (E, 2) of the mesh's boundary triangles (of every triangle, for a surface mesh): neighbours along
    the surface, never through the wall."""
    triangles = boundary_faces(mesh.cells) if mesh.cells.shape[1] == 4 else mesh.cells
    return np.asarray(triangles, np.int64)[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2)


def unmapped_holes(mesh: Mesh, unmapped: NDArray, mapped: NDArray) -> tuple[int, int]:
    """Nodes and regions of ``unmapped`` (N,) bool nodes on the mesh's surface that ``mapped`` nodes enclose: each
    region a connected patch of the surface whose every neighbour is mapped, of at least :data:`MIN_HOLE_NODES`
    nodes and :data:`MIN_HOLE_SHARE` of the map, and smaller than a quarter of it (a scar a mapping system
    exported without times)."""
    pairs = _surface_edges(mesh)
    surface = np.zeros(mesh.n_nodes, bool)
    surface[pairs.ravel()] = True
    inside = unmapped & surface
    both = pairs[inside[pairs].all(axis=1)]
    graph = coo_matrix((np.ones(len(both)), (both[:, 0], both[:, 1])), shape=(mesh.n_nodes,) * 2)
    count, component = connected_components(graph, directed=False)
    edge = pairs[inside[pairs].sum(axis=1) == 1]  # one end in a patch, the other outside it
    first_in = inside[edge[:, 0]]
    patch = component[np.where(first_in, edge[:, 0], edge[:, 1])]
    neighbour = np.where(first_in, edge[:, 1], edge[:, 0])
    edges = np.bincount(patch, minlength=count)
    to_mapped = np.bincount(patch, weights=mapped[neighbour], minlength=count)
    size = np.bincount(component[inside], minlength=count)
    smallest = max(MIN_HOLE_NODES, MIN_HOLE_SHARE * mapped.sum())
    hole = (size >= smallest) & (edges > 0) & (to_mapped == edges) & (size < 0.25 * mapped.sum())
    return int(size[hole].sum()), int(hole.sum())

"""Activation-time and tissue maps on the mesh surface, written as PNG files.

Figures are built on :class:`matplotlib.figure.Figure` with the Agg canvas,
never through ``pyplot``: nothing needs a display, the caller's matplotlib
backend is left alone, and no global figure registry keeps figures alive.
Each panel draws the boundary triangles as a :class:`Poly3DCollection` with
per-face colours (mean of the face's node values), head-light Lambert
shading and equal axis scaling.
"""

from __future__ import annotations

from collections.abc import Sequence
from os import PathLike

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize, to_rgba
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from mpl_toolkits.mplot3d import Axes3D
from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection
from numpy.typing import ArrayLike, NDArray

from shared.errors import InputError
from shared.mesh import Mesh
from shared.tissue import LABEL_NAMES
from simgen.meshes.topology import boundary_faces

__all__ = [
    "VIEWS",
    "surface_triangles",
    "plot_activation_maps",
    "plot_tissue",
    "plot_tissues",
    "plot_surfaces",
    "plot_mesh_overview",
]

#: Default camera views as (elevation, azimuth) in degrees: front and back.
VIEWS: tuple[tuple[float, float], ...] = ((12.0, 0.0), (12.0, 180.0))

_NAN_COLOUR = (0.72, 0.72, 0.72, 1.0)
_TISSUE_COLOURS = {
    label: (LABEL_NAMES[label], colour)
    for label, colour in zip(sorted(LABEL_NAMES), ("#efd3c4", "#f28e2b", "#7a0b0b", "#5a8f5a"))
}
# Surface parts in drawing priority: a face takes the first set holding all its nodes.
_PART_COLOURS = {
    "base": ("base rim", "#9a9a9a"),
    "rv_endocardium": ("RV endocardium", "#4e79a7"),
    "endocardium": ("LV endocardium", "#e15759"),
    "epicardium": ("epicardium", "#efd3c4"),
}
_PANEL_INCHES = (3.0, 3.4)
_KEY_INCHES = 1.6
_DPI = 120


def surface_triangles(mesh: Mesh) -> NDArray[np.int32]:
    """Triangles to draw: boundary faces of a tet mesh, or the cells of a triangle mesh."""
    return boundary_faces(mesh.cells) if mesh.cell_type == "tetra" else mesh.cells


def _eye(elev: float, azim: float) -> NDArray[np.float64]:
    """Unit vector from the scene towards the camera of ``view_init(elev, azim)``."""
    e, a = np.radians(elev), np.radians(azim)
    return np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])


def _shade(rgba: NDArray, tri_points: NDArray, eye: NDArray) -> NDArray:
    """Head-light Lambert shading; ``abs`` so that face orientation does not matter."""
    normal = np.cross(tri_points[:, 1] - tri_points[:, 0], tri_points[:, 2] - tri_points[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    light = 0.55 + 0.45 * np.abs(normal @ eye)
    out = rgba.copy()
    out[:, :3] *= light[:, None]
    return out


def _facing(mesh: Mesh, faces: NDArray, eye: NDArray) -> NDArray:
    """The outward-oriented faces that face the camera: fewer depth-sorting artefacts of hidden faces."""
    p = mesh.points[faces]
    return faces[np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]) @ eye > 0]


def _draw_surface(
    ax: Axes3D, mesh: Mesh, faces: NDArray, rgba: NDArray, view: tuple[float, float], bounds: NDArray | None = None
) -> None:
    """One panel: shaded triangles, camera ``view``, equal scaling, no axes.

    ``bounds`` (2, 3): the box to show (default: the mesh's bounding box).
    """
    tri_points = mesh.points[faces]
    shaded = _shade(rgba, tri_points, _eye(*view))
    # Edges in the face colour hide the anti-aliasing seams between triangles.
    poly = Poly3DCollection(tri_points, facecolors=shaded, edgecolors=shaded, linewidths=0.3)
    ax.add_collection3d(poly)
    lo, hi = (mesh.points.min(axis=0), mesh.points.max(axis=0)) if bounds is None else bounds
    ax.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), zlim=(lo[2], hi[2]))
    ax.set_box_aspect(np.maximum(hi - lo, 1e-9 * np.ptp(mesh.points)), zoom=1.25)
    ax.view_init(elev=view[0], azim=view[1])
    ax.set_axis_off()


def _mark_node(ax: Axes3D, mesh: Mesh, node: int, view: tuple[float, float]) -> None:
    """Star at ``node`` unless it lies clearly on the far side of the vertical axis.

    Only the horizontal part of the view direction counts, so nodes near the
    long axis (the apex) are marked in every view.
    """
    p = mesh.points[node] - mesh.points.mean(axis=0)
    a = np.radians(view[1])
    if p[0] * np.cos(a) + p[1] * np.sin(a) < -0.1 * np.ptp(mesh.points[:, :2], axis=0).max() / 2:
        return
    ax.scatter(
        *mesh.points[node],
        marker="*",
        s=220,
        c="white",
        edgecolors="black",
        linewidths=1.0,
        zorder=10,
        depthshade=False,
    )


def _grid(n_rows: int, n_cols: int) -> tuple[Figure, list[list[Axes3D]]]:
    """Figure with an ``n_rows x n_cols`` grid of 3-D axes and a right margin for keys."""
    width, height = _PANEL_INCHES[0] * n_cols + _KEY_INCHES, _PANEL_INCHES[1] * n_rows + 0.4
    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    axes = [
        [
            fig.add_subplot(n_rows, n_cols, r * n_cols + c + 1, projection="3d", computed_zorder=False)
            for c in range(n_cols)
        ]
        for r in range(n_rows)
    ]
    fig.subplots_adjust(
        left=0.0, right=1 - _KEY_INCHES / width, bottom=0.02, top=1 - 0.45 / height, wspace=0.0, hspace=0.12
    )
    return fig, axes


def _key_x(fig: Figure, inches: float) -> float:
    """Figure x-coordinate ``inches`` into the right-hand key margin."""
    width = fig.get_figwidth()
    return 1 - (_KEY_INCHES - inches) / width


def _save(fig: Figure, path: str | PathLike[str]) -> None:
    fig.savefig(path, dpi=_DPI, format="png", facecolor="white")


def _check_nodal(mesh: Mesh, values: NDArray, what: str, ndim: int) -> None:
    if values.ndim != ndim or values.shape[-1] != mesh.n_nodes:
        expected = "(S, N)" if ndim == 2 else "(N,)"
        raise InputError(
            f"{what} must have shape {expected} with N = {mesh.n_nodes} nodes of mesh {mesh.name!r}, got {values.shape}"
        )


def _colour_range(values: NDArray) -> Normalize:
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return Normalize(0.0, 1.0)
    lo, hi = float(finite.min()), float(finite.max())
    return Normalize(lo, hi if hi > lo else lo + 1.0)


def plot_activation_maps(
    mesh: Mesh,
    activation: ArrayLike,
    titles: Sequence[str],
    path: str | PathLike[str],
    units: str = "ms",
    stim_nodes: Sequence[int] | None = None,
    views: Sequence[tuple[float, float]] = VIEWS,
    cmap: str = "turbo_r",
) -> None:
    """Activation-time maps, one row per simulation and one column per view, as a PNG.

    Parameters
    ----------
    mesh : triangle or tetrahedral mesh (tets are drawn through their boundary faces).
    activation : (S, N) activation times; NaN marks nodes that never activated (grey).
    titles : one title per simulation.
    path : output PNG file.
    units : time units for the colour-bar label.
    stim_nodes : optional stimulation node per simulation, drawn as a star where visible.
    views : (elevation, azimuth) camera angles in degrees, one panel each.
    cmap : colour map; the default runs red (early) to blue (late).
    """
    act = np.asarray(activation, dtype=np.float64)
    _check_nodal(mesh, act, "activation", ndim=2)
    if len(titles) != len(act):
        raise InputError(f"got {len(titles)} titles for {len(act)} activation maps")
    if stim_nodes is not None and (
        len(stim_nodes) != len(act) or not all(0 <= int(s) < mesh.n_nodes for s in stim_nodes)
    ):
        raise InputError(f"stim_nodes must give one node id in [0, {mesh.n_nodes}) per activation map")
    faces = surface_triangles(mesh)
    colour_map = ScalarMappable(norm=_colour_range(act), cmap=cmap)
    fig, axes = _grid(len(act), len(views))
    for row, (values, title) in enumerate(zip(act, titles)):
        face_values = values[faces].mean(axis=1)
        rgba = colour_map.to_rgba(face_values)
        rgba[np.isnan(face_values)] = _NAN_COLOUR
        for ax, view in zip(axes[row], views):
            _draw_surface(ax, mesh, faces, rgba, view)
            ax.set_title(f"{title}  (azimuth {view[1]:g}\N{DEGREE SIGN})", fontsize=9, pad=-4)
            if stim_nodes is not None:
                _mark_node(ax, mesh, int(stim_nodes[row]), view)
    cax = fig.add_axes((_key_x(fig, 0.15), 0.25, 0.2 / fig.get_figwidth(), 0.5))
    fig.colorbar(colour_map, cax=cax, label=f"activation time ({units})")
    if np.isnan(act).any():
        fig.legend(
            handles=[Patch(color=_NAN_COLOUR, label="not activated")],
            loc="upper left",
            bbox_to_anchor=(_key_x(fig, 0.0), 0.24),
            fontsize=8,
            frameon=False,
        )
    _save(fig, path)


def plot_tissue(mesh: Mesh, label: ArrayLike, path: str | PathLike[str], title: str = "tissue") -> None:
    """One tissue's labels on the surface, two views, as a PNG (:func:`plot_tissues` with one row)."""
    plot_tissues(mesh, np.asarray(label)[None], [title], path)


def plot_tissues(
    mesh: Mesh,
    labels: ArrayLike,
    titles: Sequence[str],
    path: str | PathLike[str],
    views: Sequence[tuple[float, float]] = VIEWS,
) -> None:
    """Tissues on the surface, one row per tissue and one column per view, as a PNG.

    ``labels`` (K, N) are node labels of :class:`shared.tissue.TissueFields`
    (:data:`shared.tissue.LABEL_NAMES`: healthy, border zone, scar core,
    fibrosis); a face takes the highest label of its nodes so that thin scars
    stay visible.
    """
    lab = np.asarray(labels)
    _check_nodal(mesh, lab, "labels", ndim=2)
    if len(titles) != len(lab):
        raise InputError(f"got {len(titles)} titles for {len(lab)} tissues")
    if not np.isin(lab, list(_TISSUE_COLOURS)).all():
        raise InputError(f"tissue labels must be in {sorted(_TISSUE_COLOURS)}, got {np.unique(lab)}")
    faces = surface_triangles(mesh)
    palette = np.array([to_rgba(_TISSUE_COLOURS[k][1]) for k in sorted(_TISSUE_COLOURS)])
    fig, axes = _grid(len(lab), len(views))
    for row, (values, title) in enumerate(zip(lab, titles)):
        rgba = palette[values[faces].max(axis=1).astype(np.intp)]
        for ax, view in zip(axes[row], views):
            _draw_surface(ax, mesh, faces, rgba, view)
            ax.set_title(f"{title}  (azimuth {view[1]:g}\N{DEGREE SIGN})", fontsize=9, pad=-4)
    _colour_key(fig, _TISSUE_COLOURS, loc="center right")
    _save(fig, path)


def _colour_key(fig, colours: dict[str, tuple[str, str]], **where) -> None:
    """A legend of coloured patches, one per ``(label, colour)`` value of ``colours``, placed by ``where``."""
    fig.legend(handles=[Patch(color=c, label=n) for n, c in colours.values()], fontsize=8, frameon=False, **where)


def plot_surfaces(
    meshes: Sequence[Mesh],
    titles: Sequence[str],
    path: str | PathLike[str],
    n_cols: int = 6,
    view: tuple[float, float] = (25.0, -60.0),
) -> None:
    """Several meshes side by side on one scale, surface parts coloured, as a PNG.

    Each panel shows a mesh's boundary with epicardium, LV / RV endocardium
    and base rim in their own colours (a face takes the first of base,
    ``rv_endocardium``, ``endocardium``, ``epicardium`` that holds all its
    nodes; others are grey). Every panel uses the same box, the union of the
    meshes' bounding boxes, so sizes compare.
    """
    if len(titles) != len(meshes) or not meshes:
        raise InputError(f"got {len(titles)} titles for {len(meshes)} meshes (need one per mesh, at least one)")
    bounds = np.stack(
        [np.min([m.points.min(axis=0) for m in meshes], axis=0), np.max([m.points.max(axis=0) for m in meshes], axis=0)]
    )
    n_cols = min(n_cols, len(meshes))
    fig, axes = _grid(-(-len(meshes) // n_cols), n_cols)
    panels = [ax for row in axes for ax in row]
    for ax, mesh, title in zip(panels, meshes, titles):
        faces = _facing(mesh, surface_triangles(mesh), _eye(*view))
        _draw_surface(ax, mesh, faces, _part_colours(mesh, faces), view, bounds)
        ax.set_title(title, fontsize=8, pad=-4)
    for ax in panels[len(meshes) :]:
        ax.set_axis_off()
    _colour_key(fig, _PART_COLOURS, loc="center right")
    _save(fig, path)


def _part_colours(mesh: Mesh, faces: NDArray) -> NDArray:
    """Face colours of the surface parts (see :func:`plot_surfaces`)."""
    rgba = np.tile(to_rgba(_NAN_COLOUR), (len(faces), 1))
    unset = np.ones(len(faces), dtype=bool)
    for name, (_, colour) in _PART_COLOURS.items():
        inside = np.zeros(mesh.n_nodes, dtype=bool)
        inside[mesh.node_sets.get(name, [])] = True
        part = unset & inside[faces].all(axis=1)
        rgba[part], unset[part] = to_rgba(colour), False
    return rgba


def plot_mesh_overview(
    mesh: Mesh,
    segments: ArrayLike,
    activation: ArrayLike,
    stim_node: int,
    path: str | PathLike[str],
    title: str,
    views: Sequence[tuple[float, float]] = VIEWS,
) -> None:
    """One mesh as a PNG: a row each for its node sets, its AHA segments (1-17) and one activation map (ms)."""
    seg = np.asarray(segments, dtype=np.float64)
    act = np.asarray(activation, dtype=np.float64)
    _check_nodal(mesh, seg[None], "segments", ndim=2)
    _check_nodal(mesh, act[None], "activation", ndim=2)
    faces = surface_triangles(mesh)
    segment_colours = ScalarMappable(norm=Normalize(0.5, 17.5), cmap="tab20")
    activation_colours = ScalarMappable(norm=_colour_range(act[None]), cmap="turbo_r")
    face_segment = np.asarray([np.bincount(f, minlength=18).argmax() for f in seg[faces].astype(int)])
    rows = [
        ("node sets", _part_colours(mesh, faces)),
        ("AHA segments", segment_colours.to_rgba(face_segment)),
        (f"activation, site {stim_node}", activation_colours.to_rgba(act[faces].mean(axis=1))),
    ]
    fig, axes = _grid(len(rows), len(views))
    for (name, rgba), row in zip(rows, axes):
        for ax, view in zip(row, views):
            _draw_surface(ax, mesh, faces, rgba, view)
            ax.set_title(f"{name}  (azimuth {view[1]:g}\N{DEGREE SIGN})", fontsize=9, pad=-4)
    _mark_node(axes[2][0], mesh, stim_node, views[0])
    fig.suptitle(title, fontsize=10)
    _colour_key(fig, _PART_COLOURS, loc="upper left", bbox_to_anchor=(_key_x(fig, 0.0), 0.97))
    cax = fig.add_axes((_key_x(fig, 0.15), 0.4, 0.2 / fig.get_figwidth(), 0.2))
    fig.colorbar(segment_colours, cax=cax, label="AHA segment", ticks=[1, 6, 7, 12, 13, 16, 17])
    cax = fig.add_axes((_key_x(fig, 0.15), 0.06, 0.2 / fig.get_figwidth(), 0.2))
    fig.colorbar(activation_colours, cax=cax, label="activation time (ms)")
    _save(fig, path)


def plot_fibres(
    mesh: Mesh, path: str | PathLike[str], title: str = "fibres", views: Sequence[tuple[float, float]] = VIEWS
) -> None:
    """The mesh's fibre directions on its epicardium as short strokes over the grey surface, one panel per view.

    Each stroke is centred on an epicardial node facing the camera (at most 1,500 per view, evenly drawn)
    and spans 1.5 mean edge lengths along the node's fibre.
    """
    if mesh.fibres is None:
        raise InputError(f"mesh {mesh.name!r} has no fibres to plot")
    nodes = mesh.node_sets.get("epicardium", mesh.node_sets.get("surface", np.arange(mesh.n_nodes)))
    half = 0.75 * mesh.mean_edge_length()
    fig, axes = _grid(1, len(views))
    for ax, view in zip(axes[0], views):
        eye = _eye(*view)
        faces = _facing(mesh, surface_triangles(mesh), eye)
        _draw_surface(ax, mesh, faces, np.tile(to_rgba(_NAN_COLOUR), (len(faces), 1)), view)
        centre = mesh.points.mean(axis=0)
        shown = nodes[(mesh.points[nodes] - centre) @ eye > 0]
        shown = shown[:: max(1, len(shown) // 1500)]
        p, f = mesh.points[shown], mesh.fibres[shown]
        lift = 0.3 * half * eye  # just above the surface, so that its faces do not hide the strokes
        ax.add_collection3d(
            Line3DCollection(
                np.stack([p - half * f + lift, p + half * f + lift], axis=1), colors="#8b1a1a", linewidths=0.9
            )
        )
    fig.suptitle(title, fontsize=9)
    _save(fig, path)


def plot_ecg(
    times_ms: NDArray[np.float64], leads: NDArray[np.float64], names: Sequence[str], path: str | PathLike, title: str
) -> None:
    """The 12 leads (12, T) in mV against ms in the usual 3 x 4 layout (I, II, III | aVR, aVL, aVF | V1-V3 |
    V4-V6), every panel on one voltage scale, over a 1 mV / 40 ms grid."""
    fig = Figure(figsize=(13, 6.5))
    FigureCanvasAgg(fig)
    axes = fig.subplots(3, 4, sharex=True, sharey=True)
    limit = 1.05 * float(np.abs(leads).max(initial=1e-9))
    for k, name in enumerate(names):
        ax = axes[k % 3, k // 3]
        ax.plot(times_ms, leads[k], color="black", lw=1.2)
        ax.set_xticks(np.arange(0.0, times_ms[-1] + 1.0, 40.0), minor=True)
        ax.grid(which="both", color="#f4a6a6", lw=0.4)
        ax.set_ylim(-limit, limit)
        ax.text(0.03, 0.85, name, transform=ax.transAxes, fontsize=11, weight="bold")
    for ax in axes[-1]:
        ax.set_xlabel("time (ms)")
    for ax in axes[:, 0]:
        ax.set_ylabel("mV")
    fig.suptitle(title)
    fig.tight_layout()
    _save(fig, path)

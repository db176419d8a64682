"""Tetrahedral fillers: fTetWild (MPL-2.0, the default install's) and TetGen (AGPL-3.0, the ``tetra`` extra).

:func:`fill` fills a closed triangle surface with tetrahedra of edge about
``length`` with one of :data:`FILLERS`:

- ``"ftetwild"``: fTetWild (Hu et al. 2020, *Fast Tetrahedral Meshing in the
  Wild*, ACM TOG 39(4)) through the ``pytetwild`` wheel. It fills any
  triangle soup, a surface that passes through itself or one merged from
  overlapping parts included (its inside is decided by winding number), and
  rebuilds the surface within an envelope of the input (:data:`ENVELOPE`
  times ``length``), so surface nodes are new ones; slower than TetGen, with
  larger smallest dihedral angles (``bench.fill``, docs/results.md).
- ``"tetgen"``: TetGen through the ``tetgen`` wheel, keeping the given
  surface as it is (no nodes inserted on it) with a radius-edge bound; it
  refuses a surface that intersects itself.
- ``"auto"`` (the default, :func:`resolve_filler`): TetGen where it is
  installed and the surface does not cross itself, so that meshes it made
  before stay the same; fTetWild otherwise, and where TetGen refuses the
  surface after all (:func:`simgen.meshes.resample.tetrahedralise`).

``pytetwild``'s package imports ``pyvista`` (for an accessor on its meshes),
which this project does not need: :func:`_ftetwild` loads its compiled
wrapper alone.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
from collections.abc import Iterator
from contextlib import contextmanager
from functools import cache
from pathlib import Path
from types import ModuleType

import numpy as np
from numpy.typing import NDArray

from shared.errors import MeshError
from simgen.meshes.folds import crossing_triangles

__all__ = ["FILLERS", "ENVELOPE", "fill", "resolve_filler", "tetgen_available"]

#: Tetrahedral fillers; ``auto`` resolves to one of the others per surface (:func:`resolve_filler`).
FILLERS = ("auto", "ftetwild", "tetgen")

#: fTetWild's envelope (how far its surface may lie from the input) as a share of the target edge length.
ENVELOPE = 0.1

_TETGEN = {
    "minratio": 1.5,
    "mindihedral": 15.0,
    "nobisect": True,
    "fixedvolume": True,
    "opt_iterations": 10,
    "optmaxdihedral": 160.0,
    "quiet": True,
}
#: Files TetGen writes into the working directory when the surface intersects itself.
_TETGEN_DEBRIS = ("_skipped.face", "_skipped.node")
#: The file fTetWild writes into the working directory on every run.
_FTETWILD_DEBRIS = ("__tracked_surface.stl",)


def tetgen_available() -> bool:
    """Whether the optional TetGen wrapper is installed."""
    return importlib.util.find_spec("tetgen") is not None


def resolve_filler(filler: str | None, points: NDArray[np.float64], tris: NDArray[np.integer], name: str) -> str:
    """The filler that runs: ``filler`` (``None``: ``"auto"``) with ``auto`` resolved on this surface.

    A TetGen request for a surface that crosses itself, or without TetGen installed, raises
    :class:`MeshError` naming fTetWild.
    """
    filler = filler or "auto"
    if filler not in FILLERS:
        raise MeshError(f"mesh {name!r}: unknown filler {filler!r}; allowed: {', '.join(map(repr, FILLERS))}")
    if filler == "ftetwild":
        return filler
    crosses = len(crossing_triangles(points, tris)) > 0
    if filler == "auto":
        return "tetgen" if tetgen_available() and not crosses else "ftetwild"
    if not tetgen_available():
        raise MeshError(
            f"mesh {name!r}: the tetgen filler needs the optional TetGen wrapper (pip install 'metapns[tetra]'; "
            "TetGen is AGPL-3.0); filler 'ftetwild' or 'auto' needs nothing more"
        )
    if crosses:
        raise MeshError(f"mesh {name!r}: the surface crosses itself, which TetGen refuses; use filler 'ftetwild'")
    return filler


def fill(
    filler: str, points: NDArray[np.float64], tris: NDArray[np.integer], length: float, name: str
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Tetrahedra of edge about ``length`` filling the closed surface ``(points, tris)`` with ``filler``
    (``"ftetwild"`` or ``"tetgen"``, as :func:`resolve_filler` gives it)."""
    if filler == "tetgen":
        return _tetgen(points, tris, length, name)
    return _ftetwild_fill(points, tris, length, name)


def _ftetwild_fill(
    points: NDArray[np.float64], tris: NDArray[np.integer], length: float, name: str
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """fTetWild at ideal edge ``length``, envelope :data:`ENVELOPE` ``length``, two threads, quietly."""
    diagonal = float(np.linalg.norm(np.ptp(points, axis=0)))
    epsilon = float(np.clip(ENVELOPE * length / diagonal, 1e-4, 5e-2))
    wrapper = _ftetwild(name)
    optimize, skip_simplify, length_factor, stop_energy, coarsen = True, False, 0.05, 10.0, False
    threads, iterations, log_level, quiet, vtk_order, no_filter = 2, 80, 6, True, False, False
    with _cleaned(_FTETWILD_DEBRIS):
        tet_points, tets = wrapper.tetrahedralize_mesh(
            np.ascontiguousarray(points, np.float64),
            np.ascontiguousarray(tris, np.uint32),
            optimize,
            skip_simplify,
            length_factor,
            float(length),
            epsilon,
            stop_energy,
            coarsen,
            threads,
            iterations,
            log_level,
            quiet,
            vtk_order,
            no_filter,
            np.empty((0, 3), np.float64),  # no background sizing field
            np.empty((0, 4), np.int32),
            np.empty(0, np.float64),
        )
    if len(tets) == 0:
        raise MeshError(f"mesh {name!r}: fTetWild found no volume inside the surface")
    return np.asarray(tet_points, np.float64), np.asarray(tets, np.int64)


@cache
def _ftetwild(name: str = "mesh") -> ModuleType:
    """pytetwild's compiled wrapper, loaded without the package (whose import needs pyvista)."""
    spec = importlib.util.find_spec("pytetwild")
    found = [] if spec is None else sorted(Path(spec.submodule_search_locations[0]).glob("PyfTetWildWrapper*"))
    if not found:
        raise MeshError(f"mesh {name!r}: filling with fTetWild needs the pytetwild wheel (pip install pytetwild)")
    loader = importlib.machinery.ExtensionFileLoader("pytetwild.PyfTetWildWrapper", str(found[0]))
    module = importlib.util.module_from_spec(
        importlib.util.spec_from_file_location(loader.name, loader.path, loader=loader)
    )
    loader.exec_module(module)
    return module


def _tetgen(
    points: NDArray[np.float64], tris: NDArray[np.integer], length: float, name: str
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """TetGen with the surface kept and tetrahedra no larger than a regular one of edge ``length``."""
    import tetgen

    try:
        with _cleaned(_TETGEN_DEBRIS):
            tet_points, tets, *_ = tetgen.TetGen(points, np.asarray(tris, np.int32)).tetrahedralize(
                maxvolume=length**3 / (6 * np.sqrt(2)), **_TETGEN
            )
    except RuntimeError as exc:  # no second try: TetGen can corrupt memory when it fails twice in a process
        raise MeshError(f"mesh {name!r}: TetGen could not fill the surface ({exc})") from None
    return np.asarray(tet_points, np.float64), np.asarray(tets, np.int64)


@contextmanager
def _cleaned(debris: tuple[str, ...]) -> Iterator[None]:
    """Remove the files of ``debris`` a filler leaves in the working directory (those there before stay)."""
    before = {name for name in debris if Path(name).exists()}
    try:
        yield
    finally:
        for name in set(debris) - before:
            Path(name).unlink(missing_ok=True)

r"""The pseudo-ECG: body-surface potentials of the heart's activity in an infinite, homogeneous volume conductor.

For an electrode at :math:`x_e` (Gima and Rudy 2002; as openCARP's phie recovery without a torso mesh)

.. math::

    \phi_e(t) = -\frac{1}{4 \pi \sigma_b} \int_H \sigma_i \nabla V_m \cdot \nabla \frac{1}{|x - x_e|} \, dV,

with ``V_m = 100 u - 80`` mV, ``sigma_i`` the intracellular conductivity tensor (the solver's relative tensor
of each element, :func:`shared.fem.conductivity_tensors`, times the tissue's ``D`` scale, times
:data:`SIGMA_I`) and ``sigma_b`` the body's (:data:`SIGMA_B`). On P1 elements ``grad V_m`` is constant per
element and ``grad(1/r)`` is taken at its centroid, so the whole operator is one dense (electrodes, nodes)
matrix (:class:`PseudoECG`), assembled once per mesh and electrode set: a simulation's ECG is one product
with its (frames, nodes) potentials.

Electrodes (:func:`standard_electrodes`): RA, LA, LL (Mason-Likar, on the torso) and V1-V6 on the chest of an
elliptic-cylinder torso placed around the heart by its own axes (:data:`TORSO`); or a user's positions in mm
(:func:`read_electrodes`). Leads (:func:`leads`): I, II, III, aVR, aVL, aVF (Einthoven and Goldberger) and
V1-V6 against Wilson's central terminal.

Left out: the torso's boundary (a bounded conductor raises the potentials near it), its inhomogeneity (lungs,
blood, bone), the blood pools as conductors, and anything the dimensionless cell model does not give (a
clinical ECG's amplitudes in mV depend on these; shapes and timing are what the pseudo-ECG gives).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from shared.errors import InputError, MeshError
from shared.fem import conductivity_tensors, element_gradients
from shared.mesh import Mesh
from shared.units import to_millivolts

__all__ = [
    "LEADS",
    "ELECTRODES",
    "ECG_ATTRS",
    "SIGMA_I",
    "SIGMA_B",
    "SHELL_MM",
    "TORSO",
    "Electrodes",
    "PseudoECG",
    "standard_electrodes",
    "read_electrodes",
    "leads",
]

#: The 12 standard leads, in the usual order.
LEADS = ("I", "II", "III", "aVR", "aVL", "aVF", "V1", "V2", "V3", "V4", "V5", "V6")
#: The electrodes the 12 leads are made of.
ELECTRODES = ("RA", "LA", "LL", "V1", "V2", "V3", "V4", "V5", "V6")
#: Intracellular conductivity along the fibres (S/m; openCARP's default 0.174) and the body's (S/m; a
#: homogeneous torso of 0.2, between blood's 0.7 and lung's 0.05-0.1).
SIGMA_I, SIGMA_B = 0.174, 0.2

#: Thickness (mm) of the wall a triangle surface stands for: the pseudo-ECG of a surface mesh integrates over
#: a shell of it, as the monodomain on a surface conducts in a shell (about a ventricular wall's 10 mm).
SHELL_MM = 10.0

#: The torso and electrode placement (mm), in a body frame around the heart's centre: x to the patient's left,
#: y anterior, z superior. The heart's long axis (base to apex) points left, anterior and down, at
#: ``long_axis``; its RV lies anterior and to the right (``rv``, made orthogonal to the long axis). The chest is
#: an elliptic cylinder about the z axis through ``centre`` (the heart 40 mm left of the midline and 60 mm
#: behind the front of the chest), semi-axes ``half_width`` and ``half_depth``. Every electrode lies on its
#: front at the given (x, z): V1 and V2 20 mm right and left of the sternum, V4 on the midclavicular line, V5
#: and V6 on the anterior and mid-axillary lines 20 mm lower, V3 between V2 and V4; the limb electrodes in
#: the Mason-Likar torso placement (below the clavicles, 150 mm either side of the midline, and the left
#: lower abdomen), as exercise and monitoring ECGs place them.
TORSO = {
    "long_axis": (0.55, 0.45, -0.70),
    "rv": (-0.5, 0.85, 0.0),
    "centre": (-40.0, -50.0),
    "half_width": 170.0,
    "half_depth": 110.0,
    "electrodes": {
        "RA": (-190.0, 130.0),
        "LA": (110.0, 130.0),
        "LL": (60.0, -250.0),
        "V1": (-60.0, 20.0),
        "V2": (-20.0, 20.0),
        "V3": (15.0, 0.0),
        "V4": (50.0, -20.0),
        "V5": (90.0, -20.0),
        "V6": (125.0, -20.0),
    },
}


#: The mesh attribute ``ecg`` of a store that keeps ECGs: what its ``ecg_electrodes`` and its subjects' ``ecg``
#: arrays hold.
ECG_ATTRS = {
    "electrodes": list(ELECTRODES),
    "leads": list(LEADS),
    "units": "mV",
    "sigma_i_S_per_m": SIGMA_I,
    "sigma_b_S_per_m": SIGMA_B,
    "model": "pseudo-ECG, infinite homogeneous volume conductor; electrodes on the standard torso (docs/method.md)",
}


@dataclass(frozen=True)
class Electrodes:
    """Named electrode positions (E, 3) in the mesh's coordinates (mm)."""

    names: tuple[str, ...]
    positions: NDArray[np.float64]

    def __post_init__(self) -> None:
        positions = np.asarray(self.positions, dtype=np.float64)
        if positions.shape != (len(self.names), 3) or not np.all(np.isfinite(positions)):
            raise InputError(f"electrodes: {len(self.names)} names need ({len(self.names)}, 3) finite positions in mm")
        if len(set(self.names)) != len(self.names):
            raise InputError(f"electrodes: names must be unique, got {list(self.names)}")
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "positions", positions)

    def position(self, name: str) -> NDArray[np.float64]:
        return self.positions[self.names.index(name)]


def body_frame(mesh: Mesh) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The heart's centre (its nodes' centroid) and the rotation ``R`` (3, 3) from the body frame of
    :data:`TORSO` to the mesh's coordinates (columns: the body's x, y, z axes in mesh coordinates)."""
    if mesh.axis is None:
        raise MeshError(f"mesh {mesh.name!r}: placing ECG electrodes needs the heart's long axis (apex, base)")
    heart_long = mesh.axis.apex - mesh.axis.base
    heart = _orthonormal(heart_long, mesh.axis.reference)
    body = _orthonormal(np.asarray(TORSO["long_axis"]), np.asarray(TORSO["rv"]))
    return mesh.points.mean(axis=0), heart @ body.T


def _orthonormal(first: NDArray[np.float64], second: NDArray[np.float64]) -> NDArray[np.float64]:
    """Columns: ``first`` normalised, ``second``'s part orthogonal to it normalised, their cross product."""
    a = np.asarray(first, float) / np.linalg.norm(first)
    b = np.asarray(second, float) - (np.asarray(second, float) @ a) * a
    b /= np.linalg.norm(b)
    return np.column_stack([a, b, np.cross(a, b)])


def standard_electrodes(mesh: Mesh) -> Electrodes:
    """RA, LA, LL and V1-V6 placed around ``mesh`` by its axes in the torso of :data:`TORSO`."""
    centre, rotation = body_frame(mesh)
    cx, cy = TORSO["centre"]
    body = {}
    for name, (x, z) in TORSO["electrodes"].items():
        u = np.clip((x - cx) / TORSO["half_width"], -1.0, 1.0)
        body[name] = np.array([x, cy + TORSO["half_depth"] * np.sqrt(1.0 - u * u), z])  # on the chest's front
    positions = np.array([centre + rotation @ body[name] for name in ELECTRODES])
    return Electrodes(ELECTRODES, positions)


def read_electrodes(path: str | Path) -> Electrodes:
    """Electrodes from a text file of ``name, x, y, z`` lines (mm, the mesh's coordinates; ``#`` starts a
    comment); :class:`InputError` names the file and line of anything else."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise InputError(f"{path}: cannot read the electrode file ({exc.strerror or exc})") from None
    names, positions = [], []
    for number, line in enumerate(lines, 1):
        fields = [f.strip() for f in line.split("#", 1)[0].split(",")]
        if fields == [""]:
            continue
        try:
            if len(fields) != 4 or not fields[0]:
                raise ValueError
            xyz = [float(v) for v in fields[1:]]
        except ValueError:
            raise InputError(f"{path}:{number}: expected 'name, x, y, z' (mm), got {line.strip()!r}") from None
        names.append(fields[0])
        positions.append(xyz)
    if not names:
        raise InputError(f"{path}: no electrodes (lines 'name, x, y, z' in mm)")
    return Electrodes(tuple(names), np.array(positions))


@dataclass(frozen=True)
class PseudoECG:
    """The pseudo-ECG operator of one mesh, tissue and electrode set: ``matrix`` (E, N) maps nodal ``V_m``
    (mV) to the electrodes' potentials (mV)."""

    electrodes: Electrodes
    matrix: NDArray[np.float64]

    @classmethod
    def assemble(
        cls,
        mesh: Mesh,
        electrodes: Electrodes,
        scale: NDArray[np.float64] | None = None,
        anisotropy: float | None = None,
        sheet_anisotropy: float | None = None,
        sigma_i: float = SIGMA_I,
        sigma_b: float = SIGMA_B,
    ) -> PseudoECG:
        """The operator of ``mesh`` (tetrahedra, or triangles as a shell :data:`SHELL_MM` thick) with the
        tissue's diffusivity ``scale`` per node (``None``: 1), the fibres' ``anisotropy`` and the sheets'
        ``sheet_anisotropy`` (``None``: isotropic), the tensor the simulation conducts with
        (:func:`~shared.fem.conductivity_tensors`); see the module docstring."""
        grads, volume = element_gradients(mesh.points, mesh.cells)  # (M, k, 3), (M,)
        if mesh.cell_type != "tetra":  # a surface: a shell of the wall's thickness
            volume = volume * SHELL_MM
        centroids = mesh.points[mesh.cells].mean(axis=1)
        d = np.ones(mesh.n_nodes) if scale is None else np.asarray(scale, float)
        weight = sigma_i / (4.0 * np.pi * sigma_b) * volume * d[mesh.cells].mean(axis=1)
        if (anisotropy or 1.0) != 1.0 or (sheet_anisotropy or 1.0) != 1.0:
            tensors = conductivity_tensors(mesh, anisotropy or 1.0, sheet_anisotropy or 1.0)
            grads = np.einsum("mde,mke->mkd", tensors, grads)
        matrix = np.zeros((len(electrodes.names), mesh.n_nodes))
        for e, x_e in enumerate(electrodes.positions):
            offset = centroids - x_e
            distance = np.linalg.norm(offset, axis=1)
            if distance.min() < 1e-9:
                raise InputError(f"electrode {electrodes.names[e]} lies on the heart (at an element's centroid)")
            inverse_r_gradient = -offset / distance[:, None] ** 3  # grad(1/|x - x_e|) at each centroid
            per_corner = -np.einsum("mkd,md->mk", grads, inverse_r_gradient) * weight[:, None]
            np.add.at(matrix[e], mesh.cells.ravel(), per_corner.ravel())
        return cls(electrodes, matrix)

    def potentials(self, u: NDArray[np.floating]) -> NDArray[np.float64]:
        """Electrode potentials (..., E, T) in mV of the dimensionless ``u`` (..., T, N) over time."""
        vm = to_millivolts(np.asarray(u, np.float64))
        return np.swapaxes(vm @ self.matrix.T, -1, -2)

    def lead_matrix(self) -> NDArray[np.float64]:
        """(12, N): the 12 leads (mV) of a potential field ``u`` (N,) are ``lead_matrix() @ u``.

        Linear in ``u`` itself: each row of :attr:`matrix` sums to zero (the P1 gradients of an element sum to
        zero), so the resting offset of ``V_m = 100 u - 80`` drops out of every electrode's potential.
        """
        return (to_millivolts(1.0) - to_millivolts(0.0)) * leads(self.matrix[None], self.electrodes)[0]


def leads(potentials: NDArray[np.float64], electrodes: Electrodes) -> NDArray[np.float64]:
    """The 12 leads of :data:`LEADS` (..., 12, T) from electrode potentials (..., E, T) holding
    :data:`ELECTRODES`: Einthoven's I, II, III, Goldberger's aVR, aVL, aVF, and V1-V6 against Wilson's
    central terminal ``(RA + LA + LL) / 3``."""
    missing = sorted(set(ELECTRODES) - set(electrodes.names))
    if missing:
        raise InputError(f"the 12-lead ECG needs electrodes {list(ELECTRODES)}; missing {missing}")
    p = {name: potentials[..., electrodes.names.index(name), :] for name in ELECTRODES}
    ra, la, ll = p["RA"], p["LA"], p["LL"]
    wilson = (ra + la + ll) / 3.0
    limb = [la - ra, ll - ra, ll - la, ra - (la + ll) / 2, la - (ra + ll) / 2, ll - (ra + la) / 2]
    return np.stack(limb + [p[f"V{i}"] - wilson for i in range(1, 7)], axis=-2)

"""VAE-BO: Bayesian optimisation in the latent space of a VAE of tissue maps.

On the subject's mesh, a library of random geodesic scars
(:func:`learner.baselines.tissue_library.scar_library`) trains a small
:class:`~learner.baselines.tissue_vae.TissueVAE`; BO then searches the latent
box ``[-3, 3]^d`` (three prior standard deviations). A latent point decodes
to an excitability map, the diffusivity follows ``a`` as in FS-BO, and the
map is simulated. The library and the VAE depend only on the mesh, so they are
built once per mesh and reused by later fits on it.
"""

from __future__ import annotations

import hashlib
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from learner.baselines.base import PersonalisationBaseline, fields_from_excitability
from learner.baselines.tissue_library import scar_library
from learner.baselines.tissue_vae import TissueVAE, train_tissue_vae
from shared.errors import InputError
from shared.mesh import Mesh
from shared.tissue import TissueFields

__all__ = ["VAEBO"]


class VAEBO(PersonalisationBaseline):
    """Bayesian optimisation of a VAE's latent code of the excitability map.

    Parameters
    ----------
    latent : VAE latent dimension (the search dimension).
    library_size : maps in the training library (healthy + random scars).
    latent_box : the search box is ``[-latent_box, latent_box]^latent``.
    epochs, hidden : VAE training length and width.
    **options : budget, initial, seed, restarts, raw_samples, simulator:
        as for :class:`~learner.baselines.base.PersonalisationBaseline`;
        ``seed`` also seeds the library and the VAE.
    """

    name = "vae-bo"

    def __init__(
        self,
        latent: int = 3,
        library_size: int = 300,
        latent_box: float = 3.0,
        epochs: int = 200,
        hidden: int = 128,
        **options: Any,
    ) -> None:
        if isinstance(latent, bool) or not isinstance(latent, (int, np.integer)) or latent < 1:
            raise InputError(f"latent must be an integer >= 1, got {latent!r}")
        if isinstance(library_size, bool) or not isinstance(library_size, (int, np.integer)) or library_size < 2:
            raise InputError(f"library_size must be an integer >= 2, got {library_size!r}")
        if not (np.isfinite(latent_box) and latent_box > 0):
            raise InputError(f"latent_box must be > 0, got {latent_box!r}")
        self.latent, self.library_size, self.latent_box = int(latent), int(library_size), float(latent_box)
        self.epochs, self.hidden = int(epochs), int(hidden)
        self.vae: TissueVAE | None = None
        self._vaes: dict[str, TissueVAE] = {}
        super().__init__(**options)

    @property
    def dim(self) -> int:
        return self.latent

    def _prepare(self, mesh: Mesh) -> NDArray[np.float64]:
        key = _mesh_key(mesh)
        if key not in self._vaes:
            maps = scar_library(mesh, self.library_size, seed=self.settings.seed)
            self._vaes[key] = train_tissue_vae(
                maps, latent=self.latent, hidden=self.hidden, epochs=self.epochs, seed=self.settings.seed
            )
        self.vae = self._vaes[key]
        return np.array([[-self.latent_box] * self.latent, [self.latent_box] * self.latent])

    def tissue_at(self, params: ArrayLike) -> TissueFields:
        """Tissue fields of the map the VAE decodes from latent point ``params``."""
        if self.vae is None:
            raise InputError("VAEBO has no trained VAE yet: call fit() first")
        z = np.asarray(params, dtype=np.float64)
        if z.shape != (self.latent,):
            raise InputError(f"VAEBO expects a latent point of shape ({self.latent},), got {z.shape}")
        return fields_from_excitability(self.vae.decode(z))

    def _repr_fields(self) -> dict[str, Any]:
        return {"latent": self.latent, "library_size": self.library_size, **super()._repr_fields()}


def _mesh_key(mesh: Mesh) -> str:
    """Hash of a mesh's points and cells: the VAE cache key."""
    h = hashlib.sha256()
    for arr in (np.ascontiguousarray(mesh.points, np.float64), np.ascontiguousarray(mesh.cells, np.int32)):
        h.update(f"{arr.shape};".encode())
        h.update(arr.tobytes())
    return h.hexdigest()[:24]

"""FS-BO: Bayesian optimisation of per-region excitability on a few-segment division of the mesh.

The tissue model has one excitability ``a_r`` per region ``r`` of
:func:`learner.baselines.regions.mesh_regions` (seven by default, like the
paper's seven-segment division); every node takes its region's value and the
diffusivity follows ``a`` (:func:`learner.baselines.base.diffusivity_from_excitability`),
so a scarred region both resists excitation and slows conduction, as scar does
in the data. The search box is ``[0.15, 0.5]`` per region: healthy to dense scar,
which contains the data's tissue settings (the paper too bounds FS-BO so).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from learner.baselines.base import A_HEALTHY, A_SCAR, PersonalisationBaseline, fields_from_excitability
from learner.baselines.regions import DEFAULT_REGIONS, mesh_regions
from shared.errors import InputError
from shared.mesh import Mesh
from shared.tissue import TissueFields

__all__ = ["FSBO"]


class FSBO(PersonalisationBaseline):
    """Few-segment Bayesian optimisation of tissue excitability.

    Parameters
    ----------
    regions : number of mesh regions, one excitability each (the search dimension).
    a_bounds : search interval of each region's excitability.
    **options : budget, initial, seed, restarts, raw_samples, simulator:
        as for :class:`~learner.baselines.base.PersonalisationBaseline`.
    """

    name = "fs-bo"

    def __init__(
        self,
        regions: int = DEFAULT_REGIONS,
        a_bounds: tuple[float, float] = (A_HEALTHY, A_SCAR),
        **options: Any,
    ) -> None:
        if isinstance(regions, bool) or not isinstance(regions, (int, np.integer)) or regions < 1:
            raise InputError(f"regions must be an integer >= 1, got {regions!r}")
        lo, hi = (float(v) for v in a_bounds)
        if not (np.isfinite(lo) and np.isfinite(hi) and 0.05 <= lo < hi <= 0.5):
            raise InputError(f"a_bounds must satisfy 0.05 <= low < high <= 0.5, got {a_bounds!r}")
        self.regions, self.a_bounds = int(regions), (lo, hi)
        self.labels: NDArray[np.int64] | None = None
        super().__init__(**options)

    @property
    def dim(self) -> int:
        return self.regions

    def _prepare(self, mesh: Mesh) -> NDArray[np.float64]:
        self.labels = mesh_regions(mesh, self.regions)
        return np.array([[self.a_bounds[0]] * self.regions, [self.a_bounds[1]] * self.regions])

    def tissue_at(self, params: ArrayLike) -> TissueFields:
        """Each node takes its region's excitability ``params[r]``."""
        if self.labels is None:
            raise InputError("FSBO has no mesh regions yet: call fit() first")
        a = np.asarray(params, dtype=np.float64)
        if a.shape != (self.regions,):
            raise InputError(f"FSBO expects {self.regions} region excitabilities, got shape {a.shape}")
        return fields_from_excitability(np.clip(a, *self.a_bounds)[self.labels])

    def _repr_fields(self) -> dict[str, Any]:
        return {"regions": self.regions, "a_bounds": self.a_bounds, **super()._repr_fields()}

"""The simulator as a plug-in: what a personalisation baseline may ask of a cardiac model.

``learner`` never imports ``simgen``; a baseline that must run the physics model
(few-shot Bayesian optimisation of tissue parameters) asks for a backend by name
through the ``metapns.simulators`` entry-point group, which ``simgen`` fills
(``aliev-panfilov``, declared in ``pyproject.toml``). The contract is only this
protocol on shared types, as xarray's backends plug in through
``BackendEntrypoint``.
"""

from __future__ import annotations

from collections.abc import Mapping
from importlib.metadata import entry_points
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from shared.errors import InputError
from shared.mesh import Mesh
from shared.tissue import TissueFields

__all__ = ["SimulatorPlugin", "ENTRY_POINT_GROUP", "available_simulators", "load_simulator"]

ENTRY_POINT_GROUP = "metapns.simulators"


@runtime_checkable
class SimulatorPlugin(Protocol):
    """A cardiac model that maps tissue fields and stimulation sites to full-mesh sequences."""

    def simulate(
        self, mesh: Mesh, tissue: TissueFields, sites: NDArray[np.integer], solver: Mapping[str, Any]
    ) -> NDArray[np.float32]:
        """Sequences ``(S, T, N)`` of ``u`` for stimulation nodes ``sites``.

        ``solver`` holds solver settings by name (a store's ``spec["solver"]``
        table), so a baseline simulates exactly as the dataset was built.
        """
        ...


def available_simulators() -> list[str]:
    """Names of the installed simulator plug-ins."""
    return sorted(ep.name for ep in entry_points(group=ENTRY_POINT_GROUP))


def load_simulator(name: str = "aliev-panfilov") -> SimulatorPlugin:
    """Instantiate the backend registered as ``name``."""
    found = [ep for ep in entry_points(group=ENTRY_POINT_GROUP) if ep.name == name]
    if not found:
        raise InputError(
            f"no simulator plug-in {name!r} is installed (have: {available_simulators() or 'none'}); "
            "install the project (`pip install -e .`) so simgen registers its entry point"
        )
    backend = found[0].load()()
    if not isinstance(backend, SimulatorPlugin):
        raise InputError(f"simulator plug-in {name!r} does not implement SimulatorPlugin.simulate")
    return backend

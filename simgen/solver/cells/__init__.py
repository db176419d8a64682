"""Cell models: the ionic part of the monodomain equation, one module each, used by every integrator.

A cell model is a frozen dataclass of its parameters (what a spec's ``[solver.model]`` table
holds) with:

* ``name``, ``title``, ``citation``, ``equations``: how stores, cards and docs name it;
* ``constants()``: its parameters as the float32 named tuple the kernels take;
* a rate function ``rates(u, v, lap, a, c)`` registered for that tuple's class
  (:func:`~simgen.solver.cells.ops.register_rates`): ``(du/dt, dv/dt)`` with the diffusion term
  ``lap``, written once over the operations of :mod:`simgen.solver.cells.ops`, so the numba kernels
  (scalars and SIMD vectors) and the torch backend run the same text;
* ``max_rate`` (the reaction's stiffness, for the explicit stability limit), ``dt_accuracy`` (the
  step the reaction needs), ``resting_v`` (the second variable at rest), ``front_speed(D, a)`` and
  ``apd_scaled(scale)`` (the model with ``scale`` times its action-potential duration: a tissue's
  :attr:`~shared.tissue.TissueSpec.apd_scale`).

Both state variables live on the nodes; ``u`` is the normalised potential in both models.
"""

from __future__ import annotations

from typing import Union

from shared.errors import ConfigError
from simgen.solver.cells.aliev_panfilov import APParams
from simgen.solver.cells.mitchell_schaeffer import MSParams

__all__ = ["CellModel", "CELL_MODELS", "APParams", "MSParams", "cell_model", "with_apd_scale"]

#: Any cell model's parameters.
CellModel = Union[APParams, MSParams]  # noqa: UP007 - a runtime union that shared.config converts from TOML

#: Cell models by name.
CELL_MODELS: dict[str, type] = {m.name: m for m in (APParams, MSParams)}


def cell_model(name: str, **params: float) -> CellModel:
    """The cell model ``name`` (:data:`CELL_MODELS`) with ``params``; a :class:`ConfigError` names the choices."""
    if name not in CELL_MODELS:
        raise ConfigError(f"unknown cell model {name!r}; allowed: {', '.join(map(repr, CELL_MODELS))}")
    return CELL_MODELS[name](**params)


def with_apd_scale(model: CellModel, scale: float | None) -> CellModel:
    """``model`` with ``scale`` times its action-potential duration (``None``: ``model`` itself), as a tissue's
    :attr:`~shared.tissue.TissueSpec.apd_scale` runs it."""
    return model if scale is None else model.apd_scaled(scale)

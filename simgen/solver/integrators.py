"""The time integrators, in one registry: what each is called, how it picks its step, how stores name it.

The CLI's ``--integrator`` choices and help, spec and :class:`~simgen.solver.simulate.SolverConfig`
validation, the store's ``simulation.model`` wording and every reader of a subject's recorded
integrator (resume, repair, verify, the dataset card, through
:func:`shared.reader.integrator_of`) come from :data:`INTEGRATORS`. The kernels that run them:
:mod:`simgen.solver.kernels` (Euler), :mod:`simgen.solver.rkc_kernel` (RKC2),
:mod:`simgen.solver.imex_kernel` and :mod:`simgen.solver.imex_cg` (IMEX), each also in torch.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from shared.errors import ConfigError
from simgen.solver.timestep import choose_imex_step, choose_rkc_step, choose_time_step

__all__ = ["Integrator", "INTEGRATORS", "AUTO", "check_integrator", "integrator_help", "choose_step"]

#: The setting that picks Euler or IMEX per mesh (:func:`simgen.solver.simulate.assemble`).
AUTO = "auto"


@dataclass(frozen=True)
class Integrator:
    """A time integrator: ``name`` (spec, CLI, subject record), ``title`` (the store's ``simulation.model``),
    ``help`` (the CLI's words) and ``step(lambda_max, model, dt, interval) -> (dt, steps per frame, stages)``
    (``None`` for ``auto``, which resolves to another)."""

    name: str
    title: str
    help: str
    step: Callable[..., tuple[float, int, int]] | None


def _euler(lambda_max: float, model, dt: float | None, interval: float) -> tuple[float, int, int]:
    return (*choose_time_step(lambda_max, model.max_rate, dt, interval, model.dt_accuracy), 1)


def _rkc(lambda_max: float, model, dt: float | None, interval: float) -> tuple[float, int, int]:
    return choose_rkc_step(lambda_max, model.max_rate, dt, interval, model.dt_accuracy)


def _imex(lambda_max: float, model, dt: float | None, interval: float) -> tuple[float, int, int]:
    return (*choose_imex_step(dt, model.max_rate, interval, model.dt_accuracy), 1)


#: Every integrator by name; the first three run, ``auto`` picks one of them per mesh.
INTEGRATORS: dict[str, Integrator] = {
    i.name: i
    for i in (
        Integrator("euler", "forward Euler", "forward Euler at the stable step", _euler),
        Integrator(
            "rkc",
            "second-order Runge-Kutta-Chebyshev (RKC2)",
            "RKC2 at the accuracy step, as many stages as the mesh's stiffness needs",
            _rkc,
        ),
        Integrator(
            "imex",
            "implicit-explicit SBDF2 (implicit diffusion)",
            "implicit diffusion: no element limits the step",
            _imex,
        ),
        Integrator(
            AUTO,
            "forward Euler or implicit-explicit SBDF2 per subject (subject attribute solver.integrator)",
            "the cheaper of euler and imex on this mesh",
            None,
        ),
    )
}


def check_integrator(name: str) -> str:
    """``name`` if it is in :data:`INTEGRATORS`, else a :class:`ConfigError` naming the choices."""
    if name not in INTEGRATORS:
        raise ConfigError(f"unknown time integrator {name!r}; allowed: {', '.join(map(repr, INTEGRATORS))}")
    return name


def integrator_help() -> str:
    """The CLI's ``--integrator`` help: every choice with its words."""
    return "Time integrator: " + "; ".join(f"'{i.name}' ({i.help})" for i in INTEGRATORS.values()) + "."


def choose_step(name: str, lambda_max: float, model, dt: float | None, interval: float) -> tuple[float, int, int]:
    """Time step, steps per frame and operator products per step of integrator ``name`` (not ``auto``)."""
    return INTEGRATORS[name].step(lambda_max, model, dt, interval)

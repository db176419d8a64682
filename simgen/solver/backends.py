"""Which solver backend runs a simulation, and how far its results may be from numba's.

``numba`` is the fused CPU kernel (:mod:`simgen.solver.kernels`), ``torch``
the same steps on any torch device (:mod:`simgen.solver.torch_kernel`),
``auto`` torch on CUDA where a GPU is present and numba otherwise
(docs/solver-backends.md). Nothing here imports torch unless a torch backend
is asked for.
"""

from __future__ import annotations

from shared.errors import ConfigError, InputError

__all__ = ["BACKENDS", "BACKEND_TOLERANCE", "check_backend", "resolve_backend"]

#: Solver backends: the numba CPU kernel, the torch steps on a torch device, torch on CUDA where a GPU is present.
BACKENDS = ("numba", "torch", "auto")

#: How far results of another backend may be from numba's (``simgen verify`` of a store built with torch): max
#: abs difference of u, and of activation times in time steps, with never-activated nodes the same. Measured
#: torch on the CPU against numba: <= 1.5e-5 and <= 0.0035 steps (docs/solver-backends.md); the margin is
#: for GPU sums in other orders, not measured yet.
BACKEND_TOLERANCE = (1e-3, 1.0)


def check_backend(backend: str) -> str:
    """``backend`` if it is one of :data:`BACKENDS`, else :class:`ConfigError` naming them."""
    if backend not in BACKENDS:
        raise ConfigError(f"unknown solver backend {backend!r}; allowed: {', '.join(map(repr, BACKENDS))}")
    return backend


def resolve_backend(backend: str, device: str | None = None) -> tuple[str, str | None]:
    """The backend and torch device that run: ``("numba", None)`` or ``("torch", device)``.

    ``"torch"`` runs on ``device`` (``None``: ``cuda`` where torch finds a GPU,
    else ``cpu``; checked by :func:`simgen.solver.torch_kernel.torch_device`).
    ``"auto"`` is torch on ``device`` (default ``"cuda"``) when that is a CUDA
    device and torch finds a GPU, else numba. Both import torch; ``"numba"``
    does not, and refuses a device other than the CPU.
    """
    check_backend(backend)
    if backend == "numba":
        if device not in (None, "cpu"):
            raise InputError(f"device {device!r} needs backend 'torch' or 'auto': the numba backend runs on the CPU")
        return "numba", None
    import torch

    from simgen.solver.torch_kernel import torch_device

    if backend == "auto" and not ((device or "cuda").startswith("cuda") and torch.cuda.is_available()):
        return "numba", None
    return "torch", str(torch_device(device or ("cuda" if backend == "auto" else None)))

"""Process-level settings: the device (and hierarchies placed on it), mixed precision, threads, the allocator."""

from __future__ import annotations

import ctypes
import ctypes.util
import re
import resource
import sys
import weakref
from contextlib import AbstractContextManager

import torch

from learner.graph.hierarchy import MeshHierarchy
from shared.errors import ConfigError

__all__ = [
    "DEVICES",
    "PRECISIONS",
    "resolve_device",
    "check_device",
    "autocast",
    "on_device",
    "tune_allocator",
    "set_threads",
    "peak_memory_mb",
]

#: What ``--device`` and ``train.device`` accept (``cuda:N`` picks GPU ``N``).
DEVICES = ("auto", "cpu", "cuda", "cuda:N")
#: ``train.precision``: fp32, or autocast to bfloat16 / float16.
PRECISIONS = {"fp32": None, "bf16": torch.bfloat16, "fp16": torch.float16}

_M_TRIM_THRESHOLD, _M_MMAP_MAX = -1, -4
_DEVICE_PATTERN = re.compile(r"auto|cpu|cuda(:\d+)?")


def check_device(spec: str, what: str = "device") -> str:
    """Refuse a device string other than ``auto``, ``cpu``, ``cuda`` or ``cuda:N``."""
    if not isinstance(spec, str) or not _DEVICE_PATTERN.fullmatch(spec):
        raise ConfigError(f"{what} must be one of {', '.join(DEVICES)}, got {spec!r}")
    return spec


def resolve_device(spec: str = "auto", local_rank: int = 0, world_size: int = 1) -> torch.device:
    """The torch device for ``spec``: ``auto`` is CUDA where available, else the CPU.

    With several processes on a host (``world_size > 1``), ``auto`` and
    ``cuda`` give each process the GPU of its local rank; a fixed ``cuda:N``
    would put them all on one GPU and is refused.
    """
    check_device(spec)
    if spec == "auto":
        spec = "cuda" if torch.cuda.is_available() else "cpu"
    if spec == "cpu":
        return torch.device("cpu")
    if not torch.cuda.is_available():
        raise ConfigError(f"device {spec!r} asked for, but torch finds no CUDA GPU (use --device cpu)")
    if spec == "cuda":
        index = local_rank if world_size > 1 else torch.cuda.current_device()
    elif world_size > 1:
        raise ConfigError(f"device {spec!r} with {world_size} processes: use 'cuda' (one GPU per local rank)")
    else:
        index = int(spec.split(":")[1])
    if index >= torch.cuda.device_count():
        raise ConfigError(f"device cuda:{index} asked for, but torch finds {torch.cuda.device_count()} GPU(s)")
    return torch.device("cuda", index)


def autocast(device: torch.device, precision: str) -> AbstractContextManager:
    """``torch.autocast`` to ``precision`` (``bf16`` / ``fp16``) on ``device``; fp32 disables it."""
    if precision not in PRECISIONS:
        raise ConfigError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    dtype = PRECISIONS[precision]
    return torch.autocast(device.type, dtype=dtype, enabled=dtype is not None)


def tune_allocator() -> bool:
    """Keep freed memory in the process instead of returning it to the OS after every step.

    glibc's default trims and unmaps large blocks on free, so each training step
    pays page faults on fresh memory again; measured 2.5x slower episodes
    (``bench/surrogate.py`` times the episode with and without it). Equivalent to ``MALLOC_MMAP_MAX_=0
    MALLOC_TRIM_THRESHOLD_=<large>``; a no-op (False) where glibc is absent.
    """
    name = ctypes.util.find_library("c")
    if not name:
        return False
    try:
        libc = ctypes.CDLL(name)
        return bool(libc.mallopt(_M_MMAP_MAX, 0)) and bool(libc.mallopt(_M_TRIM_THRESHOLD, 2**30))
    except (OSError, AttributeError):
        return False


def set_threads(threads: int) -> None:
    """Torch intra-op threads (0 leaves torch's default)."""
    if threads > 0:
        torch.set_num_threads(threads)


_PLACED: weakref.WeakKeyDictionary[MeshHierarchy, dict[torch.device, MeshHierarchy]] = weakref.WeakKeyDictionary()


def on_device(hierarchy: MeshHierarchy, device: torch.device) -> MeshHierarchy:
    """``hierarchy`` itself when it lives on ``device``, else its copy there (made once per hierarchy object)."""
    if hierarchy.graphs[0].edge_index.device == device:
        return hierarchy
    copies = _PLACED.setdefault(hierarchy, {})
    if device not in copies:
        copies[device] = hierarchy.to(device)
    return copies[device]


def peak_memory_mb() -> float:
    """This process's peak resident memory so far, in MB (``getrusage``: kB on Linux, bytes on macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (1e6 if sys.platform == "darwin" else 1e3)

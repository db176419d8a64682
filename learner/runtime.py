"""Process-level settings that make CPU training fast: threads and the glibc allocator."""

from __future__ import annotations

import ctypes
import ctypes.util

import torch

__all__ = ["tune_allocator", "set_threads"]

_M_TRIM_THRESHOLD, _M_MMAP_MAX = -1, -4


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

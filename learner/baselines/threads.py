"""Run small torch work on one intra-op thread.

The GP of a BO step (a few hundred points at most) and the tissue VAE are far
too small to gain from threads, and on a machine busy with other jobs torch's
thread pool loses badly (its threads wait on each other), so the baselines pin
themselves to one thread while they run. The pin is re-applied around each BO
step rather than once: a call into the numba simulator resets the OpenMP
thread count that torch reads.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch

__all__ = ["torch_threads"]


@contextmanager
def torch_threads(threads: int = 1) -> Iterator[None]:
    """Set torch's intra-op threads for the block and restore them after (process-wide, not thread-safe)."""
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(before)

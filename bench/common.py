"""What every bench script shares: the ``--out`` folder, the machine header and best-of timing."""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

__all__ = ["cpu_model", "machine", "machine_line", "best_of", "growth_exponent", "add_out_argument", "write_out"]

T = TypeVar("T")


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo (Linux), else the platform's processor string."""
    try:
        names = [line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name")]
    except OSError:
        names = []
    return names[0] if names else platform.processor() or platform.machine()


def machine() -> dict[str, Any]:
    """The machine a bench ran on, for its JSON: architecture, CPU model, CPU count, operating system."""
    return {
        "machine": platform.machine(),
        "cpu": cpu_model(),
        "cpus": os.cpu_count(),
        "system": f"{platform.system()} {platform.release()}",
    }


def machine_line() -> str:
    """The machine in one line, for a table's header: ``Linux x86_64, <CPU model>, 2 CPUs``."""
    return f"{platform.system()} {platform.machine()}, {cpu_model()}, {os.cpu_count()} CPUs"


def best_of(
    run: Callable[[], T], repeat: int = 3, warmup: bool = False, sync: Callable[[], object] | None = None
) -> tuple[float, T]:
    """The fastest wall time (s) of ``repeat`` calls of ``run()``, and the last call's result.

    ``warmup``: one untimed call first (JIT compilation, caches); ``sync``: called before and after
    each timed call, e.g. ``torch.cuda.synchronize``, so asynchronous device work is inside the time.
    """
    if warmup:
        run()
    best, result = float("inf"), None
    for _ in range(max(1, repeat)):
        if sync is not None:
            sync()
        start = time.perf_counter()
        result = run()
        if sync is not None:
            sync()
        best = min(best, time.perf_counter() - start)
    return best, result


def growth_exponent(size: tuple[float, float], cost: tuple[float, float]) -> float:
    """The exponent ``p`` of ``cost ~ size^p`` through two points: ``log(cost ratio) / log(size ratio)``."""
    return float(math.log(cost[1] / cost[0]) / math.log(size[1] / size[0]))


def add_out_argument(parser: argparse.ArgumentParser, name: str, default: Path | None = None) -> None:
    """``--out DIR``: the folder that receives ``NAME.md`` (the tables) and ``NAME.json`` (the numbers)."""
    parser.add_argument("--out", type=Path, default=default, help=f"folder for {name}.md (and {name}.json)")


def write_out(out: Path | None, name: str, markdown: str, data: Any = None, indent: int | None = 1) -> list[Path]:
    """Write ``out/NAME.md`` and, unless ``data`` is None, ``out/NAME.json``; nothing when ``out`` is None.

    Returns the paths written.
    """
    if out is None:
        return []
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"{name}.md"]
    paths[0].write_text(markdown)
    if data is not None:
        paths.append(out / f"{name}.json")
        paths[1].write_text(json.dumps(data, indent=indent, default=float))
    return paths

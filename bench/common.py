"""What every bench script shares: the ``--out`` folder, ``--publish`` to docs/results.md, the machine header
and best-of timing."""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import re
import shlex
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

__all__ = [
    "RESULTS",
    "PublishError",
    "cpu_model",
    "machine",
    "machine_line",
    "best_of",
    "growth_exponent",
    "add_out_argument",
    "write_out",
    "add_publish_argument",
    "check_publish",
    "publish",
    "publish_out",
    "blocks",
]

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


#: The page the bench scripts publish their tables to.
RESULTS = Path(__file__).resolve().parents[1] / "docs" / "results.md"
#: A line ``<!-- bench:NAME -->`` opens the block NAME, a line ``<!-- /bench:NAME -->`` closes it (markers
#: quoted within a line are text).
MARKER = re.compile(r"^<!-- (/?)bench:([\w.-]+) -->[ \t]*$", re.MULTILINE)


class PublishError(ValueError):
    """A page's bench blocks are missing, unbalanced or duplicated."""


def blocks(text: str, page: Path | str = "the page") -> list[str]:
    """The names of the bench blocks of ``text``, in order; raises :class:`PublishError` unless every block is
    opened once, closed once after it, and holds no other block."""
    names: list[str] = []
    open_name: str | None = None
    for m in MARKER.finditer(text):
        closing, name = m.group(1) == "/", m.group(2)
        line = text.count("\n", 0, m.start()) + 1
        if not closing:
            if open_name is not None:
                raise PublishError(f"{page}:{line}: block {name!r} opens inside block {open_name!r}")
            if name in names:
                raise PublishError(f"{page}:{line}: block {name!r} appears twice")
            open_name = name
        elif name != open_name:
            raise PublishError(f"{page}:{line}: <!-- /bench:{name} --> closes a block that is not open")
        else:
            names.append(name)
            open_name = None
    if open_name is not None:
        raise PublishError(f"{page}: block {open_name!r} is opened and never closed (<!-- /bench:{open_name} -->)")
    return names


def check_publish(section: str | None, page: Path = RESULTS) -> None:
    """Raise :class:`PublishError` unless ``page`` has the block ``section`` (None: nothing to check).

    Scripts call it before they measure, so that a long run does not end in a missing block."""
    if section is None:
        return
    present = blocks(page.read_text(), page)
    if section not in present:
        raise PublishError(
            f"{page} has no block {section!r}: add the lines <!-- bench:{section} --> and <!-- /bench:{section} --> "
            f"where its table belongs (blocks there: {', '.join(present) or 'none'})"
        )


def publish(section: str, markdown: str, page: Path = RESULTS) -> Path:
    """Replace the text between ``<!-- bench:SECTION -->`` and ``<!-- /bench:SECTION -->`` of ``page`` with
    ``markdown``; the rest of the page is left byte for byte. Returns ``page``.

    Raises :class:`PublishError` when the page lacks the block or its markers are unbalanced."""
    check_publish(section, page)
    text = page.read_text()
    start, end = (m for m in MARKER.finditer(text) if m.group(2) == section)
    page.write_text(f"{text[: start.end()]}\n\n{markdown.strip(chr(10))}\n\n{text[end.start() :]}")
    return page


def add_publish_argument(parser: argparse.ArgumentParser, section: str) -> None:
    """``--publish [SECTION]``: write the tables into the block SECTION of docs/results.md (default: ``section``)."""
    parser.add_argument(
        "--publish",
        nargs="?",
        const=section,
        metavar="SECTION",
        help=f"replace the block <!-- bench:SECTION --> of docs/results.md with the tables, the command and the "
        f"machine (default SECTION: {section})",
    )


def publish_out(section: str | None, script: str, markdown: str, page: Path = RESULTS) -> Path | None:
    """:func:`publish` ``markdown`` under a line naming the command (``bench.SCRIPT`` with this process's
    arguments) and the machine; nothing when ``section`` is None. Returns the page written."""
    if section is None:
        return None
    command = " ".join([".venv/bin/python", "-m", f"bench.{script}", shlex.join(sys.argv[1:])]).strip()
    return publish(section, f"Command: `{command}`. Machine: {machine_line()}.\n\n{markdown}", page)

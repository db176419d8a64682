"""Helpers of the simgen and learner command lines: one-line errors, lists of ids, Markdown output.

Bad input exits with code 2 and one line naming the problem, never a
traceback: an :class:`~shared.errors.InputError`, or an :class:`OSError` by
which the file system refuses a path the user gave (permission, read-only,
no space, a file where a folder is expected). Any other exception is a bug
and keeps its traceback.
"""

from __future__ import annotations

import errno
import math
import re
from collections import Counter
from pathlib import Path
from typing import Annotated, NoReturn

import typer
from rich.console import Console
from rich.markup import escape

from shared.errors import InputError

__all__ = [
    "MAX_SEED",
    "PATH_ERRNOS",
    "SiteXyzOpt",
    "SiteRegionOpt",
    "SiteToleranceOpt",
    "fail",
    "finite",
    "one_line",
    "path_error",
    "parse_ids",
    "print_markdown",
]

#: Largest seed an option takes (NumPy's and torch's generators take 32 bits everywhere).
MAX_SEED = 2**32 - 1

#: errno values of a file system refusing a path: bad input, not a bug.
PATH_ERRNOS = frozenset(
    {
        errno.EACCES,
        errno.EPERM,
        errno.EROFS,
        errno.ENOSPC,
        errno.EDQUOT,
        errno.EISDIR,
        errno.ENOTDIR,
        errno.EEXIST,
    }
)

# simgen and learner make folders with exist_ok=True: EEXIST means a file stands where a folder is to be made.
_HINTS = {
    errno.EEXIST: " (a file where a folder is expected)",
    errno.ENOTDIR: " (a file where a folder is expected)",
    errno.EISDIR: " (a folder where a file is expected)",
}


def path_error(exc: OSError, path: str | Path | None = None) -> InputError | None:
    """``exc`` as bad input naming its file (or ``path``); ``None`` when its errno is not in :data:`PATH_ERRNOS`."""
    if exc.errno not in PATH_ERRNOS:
        return None
    where = exc.filename or path
    message = f"{exc.strerror}{_HINTS.get(exc.errno, '')}"
    return InputError(f"{where}: {message}" if where else message)


def fail(console: Console, exc: Exception, path: str | Path | None = None) -> NoReturn:
    """Print ``exc`` on ``console`` as one line and exit with code 2; re-raise an OSError :func:`path_error` rejects."""
    error = path_error(exc, path) if isinstance(exc, OSError) else exc
    if error is None:
        raise exc
    console.print(f"[red]error:[/red] {escape(one_line(str(error)))}", soft_wrap=True)
    raise typer.Exit(code=2)


def one_line(message: str) -> str:
    """``message`` without the worker traceback a DataLoader adds to an error it re-raises.

    PyTorch re-raises an exception of a loader worker with the message
    ``Caught X in DataLoader worker process N. Original Traceback ...``, whose
    last line is ``module.X: the original message``.
    """
    if "Original Traceback" not in message:
        return message
    last = message.rstrip().splitlines()[-1]
    match = re.match(r"^[\w.]+: ", last)
    return last[match.end() :] if match else last


def finite(value: float | None) -> float | None:
    """Typer callback of a float option: refuse NaN and infinity, which a ``min=`` range lets through."""
    if value is not None and not math.isfinite(value):
        raise typer.BadParameter(f"{value} is not a finite number")
    return value


def needs(option: str, given: bool, other: str, present: bool) -> None:
    """Refuse ``option`` when it is ``given`` without ``other``, without which it would have no effect."""
    if given and not present:
        raise InputError(f"{option} has no effect without {other}: add {other} or leave {option} out")


def parse_ids(text: str, option: str) -> list[int]:
    """The comma-separated integers >= 0 of ``text``, each given once (errors name ``option``)."""
    try:
        ids = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise InputError(f"{option}: expected comma-separated integers, got {text!r}") from None
    if not ids:
        raise InputError(f"{option}: give at least one integer")
    if negative := [i for i in ids if i < 0]:
        raise InputError(f"{option}: {negative} must be >= 0")
    if repeated := sorted(i for i, n in Counter(ids).items() if n > 1):
        raise InputError(f"{option}: {repeated} given more than once; give each once")
    return ids


def print_markdown(console: Console, text: str) -> None:
    """Print Markdown ``text`` as it is: tables unwrapped at any terminal width, brackets not read as markup."""
    console.print(text, soft_wrap=True, markup=False, highlight=False)


#: Sites by position (:mod:`shared.sites`), the options of every command that takes ``--sites`` node ids.
SiteXyzOpt = Annotated[
    str | None,
    typer.Option(
        "--site-xyz",
        help="Sites as points x,y,z in mm, ';' between points: each the nearest node within --site-tolerance "
        "(simgen centres the stimulus on the point).",
    ),
]
SiteRegionOpt = Annotated[
    str | None,
    typer.Option(
        "--site-region",
        help="Sites by region, comma-separated: aha-1 ... aha-17 (AHA segments of the LV), apex, rv-free-wall; "
        "each optionally :epi (default) or :endo.",
    ),
]
SiteToleranceOpt = Annotated[
    float,
    typer.Option(min=0, callback=finite, help="Largest distance (mm) from a --site-xyz point to its node."),
]

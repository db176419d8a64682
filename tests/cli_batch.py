"""Run command lines of the real ``simgen`` / ``learner`` apps one after another in this process.

``python tests/cli_batch.py < runs.json`` reads ``[[package, arg, ...], ...]`` and prints, as JSON,
``[[exit code, output], ...]``: the code the console script would exit with and its stdout +
stderr. An exception that escapes an app is printed with its traceback (exit code 1), as the
console script would print it. One process serves many command lines, so the interpreter, typer,
torch and the simulator are imported once instead of once per command line.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import json
import sys
import traceback


def run(package: str, *args: str) -> tuple[int, str]:
    """Exit code and output of ``package args`` (``package`` is ``simgen`` or ``learner``)."""
    app = importlib.import_module(f"{package}.cli").app
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        try:
            app(list(args), prog_name=package)
            code = 0
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else int(exc.code is not None)
        except Exception:
            traceback.print_exc()
            code = 1
    return code, out.getvalue()


if __name__ == "__main__":
    json.dump([run(*argv) for argv in json.load(sys.stdin)], sys.stdout)

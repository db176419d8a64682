"""Run command lines of the real ``simgen`` / ``learner`` apps one after another in this process.

``python tests/cli_batch.py < runs.json`` reads ``[[package, arg, ...], ...]`` and prints, as JSON,
``[[exit code, output], ...]``: the code the console script would exit with and its stdout +
stderr. An exception that escapes an app is printed with its traceback (exit code 1), as the
console script would print it. One process serves many command lines, so the interpreter, typer,
torch and the simulator are imported once instead of once per command line.

``python tests/cli_batch.py --serve`` serves batches until its stdin closes: each line it reads is
one such JSON list, and it answers each with one line of JSON results. A test module keeps a
couple of these processes for all its batches, so each imports the packages once per module.
Anything else written to the process's standard output (a C library, a child process) goes to
its standard error, so the answers stay one line each.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import json
import os
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


def serve() -> None:
    """Answer each JSON line of stdin (a batch) with one JSON line of its results, until stdin closes."""
    answers = os.fdopen(os.dup(sys.stdout.fileno()), "w")
    sys.stdout.flush()
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())  # stray output, from any level, goes to stderr
    for line in sys.stdin:
        if line.strip():
            answers.write(json.dumps([run(*argv) for argv in json.loads(line)]) + "\n")
            answers.flush()


if __name__ == "__main__":
    if sys.argv[1:] == ["--serve"]:
        serve()
    else:
        json.dump([run(*argv) for argv in json.load(sys.stdin)], sys.stdout)

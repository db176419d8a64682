"""``python -m simgen.cli``: the ``simgen`` command line (as ``python -m simgen``)."""

from simgen.cli import app

app(prog_name="simgen")

"""One vocabulary across the simgen and learner commands (``--sites`` node ids, ``--site-index`` site indices,
``--site-xyz`` points, ``--site-region`` regions), and the file formats described in ``--help``."""

from __future__ import annotations

import re
from pathlib import Path

import click
import pytest
import typer
from typer.testing import CliRunner

from learner.cli import app as learner_app
from simgen.cli import app as simgen_app

ROOT = Path(__file__).resolve().parents[1]


def _params() -> list[tuple[str, click.Parameter]]:
    """(``tool command``, parameter) of every command of both tools."""
    found = []
    for tool, app in (("simgen", simgen_app), ("learner", learner_app)):
        group = typer.main.get_command(app)
        for name, command in group.commands.items():
            found.extend((f"{tool} {name}", param) for param in command.params)
    return found


def _help(param: click.Parameter) -> str:
    return (getattr(param, "help", None) or "").lower()


#: Every parameter about stimulation sites, by name, and a phrase its help must hold.
SITE_PARAMS = {
    "sites": "node id",
    "site_index": "site ind",
    "sites_per_setting": "sites per",
    "site_xyz": "x,y,z in mm",
    "site_region": "aha-1",
    "site_tolerance": "mm",
}


def _problem(param: click.Parameter) -> str:
    """What is wrong with a site parameter's name or help; ``""`` when nothing is."""
    if param.name not in SITE_PARAMS:
        return "use --sites (node ids) or --site-index (site indices)"
    if SITE_PARAMS[param.name] not in _help(param):
        return f"help lacks {SITE_PARAMS[param.name]!r}"
    if param.name == "sites" and ("ind" in _help(param) or param.opts != ["--sites"]):
        return "--sites takes node ids only"
    if param.name == "site_index" and param.opts not in (["--site-index"], ["site_index"]):
        return "site indices are --site-index (or the SITE_INDEX argument)"
    if param.name in ("site_xyz", "site_region", "site_tolerance") and param.opts != [
        f"--{param.name.replace('_', '-')}"
    ]:
        return "sites by position are --site-xyz, --site-region and --site-tolerance"
    return ""


def test_site_options_say_what_they_take():
    """Node ids (``--sites``) and site indices (``--site-index``, ``SITE_INDEX``) never share a name."""
    problems = [f"{command} {p.name}: {_problem(p)}" for command, p in _params() if "site" in p.name and _problem(p)]
    assert not problems


@pytest.mark.parametrize(
    ("app", "command", "words"),
    [
        (simgen_app, "simulate", ("TOML", "scars", "border_width", "docs/formats.md", "examples/scar.toml")),
        (simgen_app, "add-subject", ("TOML", "scars", "docs/formats.md")),
        (learner_app, "personalize", ("(K, T, N)", "V in mV", "T = 55", "docs/formats.md", "observations.npz")),
    ],
)
def test_help_documents_the_file_formats(app: typer.Typer, command: str, words: tuple[str, ...]):
    """The tissue TOML and the observation file are described in ``--help``, with the page and example."""
    wide = {"COLUMNS": "400"}  # rich sizes its help panels from COLUMNS, not from click's terminal width
    text = " ".join(CliRunner().invoke(app, [command, "--help"], env=wide).output.split())
    assert all(word in text for word in words), [word for word in words if word not in text]


def _options() -> dict[tuple[str, str], set[str]]:
    """(tool, command) -> every option spelling it takes."""
    options = {}
    for tool, app in (("simgen", simgen_app), ("learner", learner_app)):
        for name, command in typer.main.get_command(app).commands.items():
            options[tool, name] = {o for p in command.params for o in [*p.opts, *p.secondary_opts] if o.startswith("-")}
    return options


def _documented_calls(text: str) -> list[list[str]]:
    """The ``simgen ...`` / ``learner ...`` command lines of the shell blocks in Markdown ``text``."""
    calls = []
    for block in re.findall(r"```sh\n(.*?)```", text, re.DOTALL):
        for line in block.replace("\\\n", " ").splitlines():
            words = line.split("#")[0].split()
            if words and words[0] in ("simgen", "learner", "$(BIN)/simgen", "$(BIN)/learner"):
                calls.append([words[0].rsplit("/", 1)[-1], *words[1:]])
    return calls


#: Files whose shell blocks (the Makefile: its recipes) run simgen and learner commands.
DOCUMENTED = [
    "README.md",
    "Makefile",
    "deploy/README.md",
    *(str(p.relative_to(ROOT)) for p in sorted((ROOT / "docs").glob("*.md"))),
    *(str(p.relative_to(ROOT)) for p in sorted((ROOT / "learner/pretrained").glob("*/README.md"))),
]


@pytest.mark.parametrize("page", DOCUMENTED)
def test_documented_commands_take_the_options_they_are_given(page: str):
    """Every ``--option`` of a documented command line (and of the Makefile's) is one that command has."""
    options = _options()
    text = (ROOT / page).read_text()
    wrong = [
        f"{tool} {command} {word}"
        for tool, command, *args in _documented_calls(text if page.endswith(".md") else f"```sh\n{text}```")
        for word in args
        if word.startswith("--") and word.split("=")[0] not in options[tool, command]
    ]
    assert not wrong

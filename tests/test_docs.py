"""README and docs/: a short README, links that resolve, a layout naming every module folder, reference wording."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PAGES = [README, *sorted((ROOT / "docs").glob("*.md"))]
#: Every Markdown file with links to check: the pages, the model cards and the folders' READMEs.
LINKED = [
    *PAGES,
    *(p for folder in ("bench", "deploy", "learner", "simgen") for p in sorted((ROOT / folder).rglob("*.md"))),
]
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower().replace("`", ""))
    return text.replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    return {_slug(line.lstrip("#")) for line in page.read_text().splitlines() if line.startswith("#")}


def _broken_links(page: Path) -> list[str]:
    """The relative links of ``page`` whose file, or heading in a Markdown file, does not exist."""
    broken = []
    for target in LINK.findall(page.read_text()):
        if "://" in target or target.startswith("mailto:"):
            continue
        path, _, anchor = target.partition("#")
        file = (page.parent / path).resolve() if path else page
        if not file.exists() or (anchor and file.suffix == ".md" and anchor not in _anchors(file)):
            broken.append(target)
    return broken


def test_the_readme_is_short():
    assert len(README.read_text().splitlines()) <= 200


@pytest.mark.parametrize("page", LINKED, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(page: Path):
    assert not _broken_links(page)


def test_the_layout_names_every_module_folder_and_top_level_folder():
    layout = README.read_text().split("## Repository layout", 1)[1].split("\n## ", 1)[0]
    named = set(re.findall(r"([\w-]+)/", layout))
    modules = {p.parent.name for pkg in ("shared", "simgen", "learner") for p in (ROOT / pkg).rglob("*.py")}
    tracked = subprocess.run(
        ["git", "ls-tree", "-d", "--name-only", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout.split()
    missing = (modules | {name for name in tracked if not name.startswith(".")}) - named
    assert not missing


#: Goal verdicts, development history and paths outside the project.
NOT_REFERENCE = re.compile(
    r"\bgoals?\b|\bnot met\b|not adopted|this session|now fixed|/work/shared|\.\./shared", re.IGNORECASE
)


def test_user_docs_read_as_reference():
    """No goal verdicts, no development history, no paths outside the project."""
    found = [f"{page.name}: {m.group(0)}" for page in PAGES for m in NOT_REFERENCE.finditer(page.read_text())]
    assert not found


def test_licence_and_citation_agree_with_pyproject():
    import tomllib

    import yaml

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    citation = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    licence = project["license"] if isinstance(project["license"], str) else project["license"]["text"]
    assert citation["license"] == licence == "MIT" and "MIT License" in (ROOT / "LICENSE").read_text()
    assert citation["version"] == project["version"] and citation["cff-version"] == "1.2.0"
    assert "Bayesian Meta-Learning" in citation["preferred-citation"]["title"]


RESULTS = ROOT / "docs" / "results.md"
#: A figure quoted elsewhere: a link whose text holds numbers, to a section of docs/results.md.
QUOTE = re.compile(r"\[([^\]]*\d[^\]]*)\]\((?:[./]*(?:docs/)?)results\.md#([\w-]+)\)")
NUMBER = re.compile(r"\d[\d,]*(?:\.\d+)?")


def _section(anchor: str) -> str:
    """The text of docs/results.md under the heading ``anchor`` (its subsections included)."""
    lines, found, level = RESULTS.read_text().splitlines(), [], None
    for line in lines:
        depth = len(line) - len(line.lstrip("#")) if line.startswith("#") else 0
        if depth and level is not None and depth <= level:
            break
        if depth and level is None and _slug(line.lstrip("#")) == anchor:
            level = depth
        if level is not None:
            found.append(line)
    return "\n".join(found)


@pytest.mark.parametrize("page", [p for p in LINKED if p != RESULTS], ids=lambda p: str(p.relative_to(ROOT)))
def test_quoted_figures_are_those_of_their_results_block(page: Path):
    """A figure quoted outside docs/results.md links to its section there, which holds every number it quotes."""
    wrong = []
    for text, anchor in QUOTE.findall(page.read_text()):
        section = _section(anchor).replace(",", "")
        for number in NUMBER.findall(text):
            plain = number.replace(",", "")
            if not re.search(rf"(?<![\d.]){re.escape(plain)}(?![\d])", section):
                wrong.append(f"{number} of [{text}] is not in results.md#{anchor}")
    assert not wrong, "\n".join(wrong)

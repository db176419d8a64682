"""``--publish``: bench scripts write their tables into the marked blocks of docs/results.md, and only there."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from bench import common
from bench.common import PublishError, blocks, check_publish, publish, publish_out

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results.md"

PAGE = """# Results

Intro naming the markers in a line: `<!-- bench:NAME -->` is text, not a block.

## One

<!-- bench:one -->

| old | table |
|---|---|
| 1 | 2 |

<!-- /bench:one -->

Prose after one.

<!-- bench:two.refined -->
two's table
<!-- /bench:two.refined -->
tail without a final newline"""


@pytest.fixture
def page(tmp_path: Path) -> Path:
    path = tmp_path / "results.md"
    path.write_text(PAGE)
    return path


def test_publish_replaces_only_the_marked_block(page: Path) -> None:
    assert publish("one", "\n| new | table |\n|---|---|\n| 3 | 4 |\n\n", page) == page
    text = page.read_text()
    head, rest = PAGE.split("<!-- bench:one -->\n")
    _, tail = rest.split("<!-- /bench:one -->")
    assert text == f"{head}<!-- bench:one -->\n\n| new | table |\n|---|---|\n| 3 | 4 |\n\n<!-- /bench:one -->{tail}"
    assert "two's table" in text and text.endswith("tail without a final newline")
    publish("one", "| new | table |\n|---|---|\n| 3 | 4 |", page)  # the same tables again: the same page
    assert page.read_text() == text
    publish("two.refined", "2", page)
    assert page.read_text().split("<!-- bench:two.refined -->")[0] == text.split("<!-- bench:two.refined -->")[0]
    assert "<!-- bench:two.refined -->\n\n2\n\n<!-- /bench:two.refined -->\ntail" in page.read_text()


def test_a_page_without_the_block_is_refused_and_left_alone(page: Path) -> None:
    with pytest.raises(PublishError, match=r"no block 'three'.*<!-- bench:three -->.*blocks there: one, two.refined"):
        publish("three", "| x |", page)
    with pytest.raises(PublishError, match="no block 'NAME'"):  # quoted in a line: not a block
        check_publish("NAME", page)
    assert page.read_text() == PAGE
    check_publish(None, page)  # no --publish: nothing to check


@pytest.mark.parametrize(
    "text, match",
    [
        ("<!-- bench:a -->\nx\n", "'a' is opened and never closed"),
        ("x\n<!-- /bench:a -->\n", "closes a block that is not open"),
        ("<!-- bench:a -->\n<!-- bench:b -->\n<!-- /bench:b -->\n<!-- /bench:a -->\n", "'b' opens inside block 'a'"),
        ("<!-- bench:a -->\n<!-- /bench:a -->\n<!-- bench:a -->\n<!-- /bench:a -->\n", "'a' appears twice"),
        ("<!-- bench:a -->\n<!-- /bench:b -->\n", "closes a block that is not open"),
    ],
)
def test_unbalanced_markers_are_refused(tmp_path: Path, text: str, match: str) -> None:
    path = tmp_path / "results.md"
    path.write_text(text)
    with pytest.raises(PublishError, match=match):
        publish("a", "| x |", path)
    assert path.read_text() == text


def test_publish_out_names_the_command_and_the_machine(page: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    assert publish_out(None, "real_hearts", "| x |", page) is None and page.read_text() == PAGE
    monkeypatch.setattr("sys.argv", ["bench/real_hearts.py", "--nodes", "1000", "--publish", "one"])
    publish_out("one", "real_hearts", "| x |\n", page)
    block = page.read_text().split("<!-- bench:one -->\n")[1].split("<!-- /bench:one -->")[0]
    command = "`.venv/bin/python -m bench.real_hearts --nodes 1000 --publish one`"
    assert block == f"\nCommand: {command}. Machine: {common.machine_line()}.\n\n| x |\n\n"


def test_every_marker_of_the_results_page_is_opened_and_closed() -> None:
    text = RESULTS.read_text()
    names = blocks(text, RESULTS)
    assert names, "docs/results.md has no bench blocks"
    # a marker line that the pattern does not read (a typo) would leave its table unpublished
    marker_like = [line for line in text.splitlines() if re.match(r"\s*<!--\s*/?\s*bench", line)]
    assert len(marker_like) == 2 * len(names), marker_like


def test_every_block_of_the_results_page_has_a_script_that_publishes_it() -> None:
    for name in blocks(RESULTS.read_text(), RESULTS):
        script = ROOT / "bench" / f"{name.split('.')[0]}.py"
        assert script.is_file(), f"block {name!r}: no bench/{script.name}"
        assert "add_publish_argument(" in script.read_text(), f"bench/{script.name} has no --publish"


def test_a_script_refuses_a_missing_block_before_it_measures(monkeypatch: pytest.MonkeyPatch) -> None:
    from bench import preconditioners

    monkeypatch.setattr(preconditioners, "get_mesh", lambda *a, **k: pytest.fail("measured before checking"))
    with pytest.raises(PublishError, match="no block 'no-such-block'"):
        preconditioners.main(["--nodes", "300", "--publish", "no-such-block"])

"""The bench package: one common module used by every script, every script in bench/README.md, no path hacks."""

from __future__ import annotations

import ast
import importlib.util
import json
import re
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench"
SCRIPTS = sorted(p for p in BENCH.glob("*.py") if p.name not in ("__init__.py", "common.py"))


def _common():
    """bench/common.py, loaded from its file (``bench`` is run from the repository root, not installed)."""
    spec = importlib.util.spec_from_file_location("bench_common_under_test", BENCH / "common.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    names = {node.module or "" for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    names |= {
        f"bench.{a.name}"
        for n in ast.walk(tree)
        if isinstance(n, ast.ImportFrom) and n.module == "bench"
        for a in n.names
    }
    return names


def test_bench_is_a_package() -> None:
    assert (BENCH / "__init__.py").is_file() and len(SCRIPTS) >= 20


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.stem)
def test_script_uses_common_and_no_path_hack(script: Path) -> None:
    assert "bench.common" in _imports(script), f"{script.name} does not use bench.common"
    tree = ast.parse(script.read_text())
    hacks = [
        n
        for n in ast.walk(tree)
        if isinstance(n, ast.Attribute) and n.attr == "path" and isinstance(n.value, ast.Name) and n.value.id == "sys"
    ]
    assert not hacks, f"{script.name} edits sys.path"
    assert "__file__, " not in script.read_text(), f"{script.name} starts itself as a file, not as bench.{script.stem}"


def test_every_script_is_in_the_readme() -> None:
    readme = (BENCH / "README.md").read_text()
    rows = set(re.findall(r"^\| `([\w.]+)` \|", readme, flags=re.M))
    shipped = {p.name for p in SCRIPTS} | {p.name for p in BENCH.glob("*.sh")}
    assert shipped - rows == set()
    assert rows - shipped == set()  # no row for a script that is gone


def test_write_out(tmp_path: Path) -> None:
    common = _common()
    assert common.write_out(None, "x", "table") == []
    paths = common.write_out(tmp_path / "out", "x", "| a |\n", {"v": 1.5}, indent=None)
    assert [p.name for p in paths] == ["x.md", "x.json"]
    assert paths[0].read_text() == "| a |\n" and json.loads(paths[1].read_text()) == {"v": 1.5}
    assert [p.name for p in common.write_out(tmp_path / "md", "y", "text")] == ["y.md"]


def test_best_of_keeps_the_fastest_and_warms_up() -> None:
    common = _common()
    calls, syncs = [], []
    seconds, result = common.best_of(
        lambda: calls.append(1) or len(calls), 3, warmup=True, sync=lambda: syncs.append(1)
    )
    assert result == 4 and len(calls) == 4 and len(syncs) == 6 and seconds >= 0
    assert common.machine()["cpus"] >= 1 and "CPUs" in common.machine_line()


def test_scripts_run_as_modules_of_the_package() -> None:
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-m", "bench.seed_spread", "--help"], cwd=BENCH.parent, capture_output=True, text=True
    )
    assert done.returncode == 0 and "--out" in done.stdout, done.stderr


def test_growth_exponent_through_two_points() -> None:
    common = _common()
    assert common.growth_exponent((1000, 8000), (2.0, 32.0)) == pytest.approx(4 / 3)
    assert common.growth_exponent((10, 20), (5.0, 5.0)) == 0.0

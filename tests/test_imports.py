"""The project's modules import each other without a cycle, counting imports inside functions too.

Every ``import`` and ``from ... import`` of ``simgen``, ``learner``, ``shared`` and ``bench``, at module
level, inside a function or under ``if TYPE_CHECKING``, is an edge of a module graph; ``from a import b``
points at the module ``a.b`` when there is one, else at ``a``. A strongly connected component of more than
one module (or a module importing itself) is a cycle, reported as a path. The same holds between
folders (:func:`folder_graph`): two sibling subpackages never import each other both ways.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator, Mapping
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("simgen", "learner", "shared", "bench")


def module_name(path: Path, root: Path = ROOT) -> str:
    """Dotted module name of a source file (``a/b/__init__.py`` is ``a.b``)."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def project_modules(root: Path = ROOT, packages: tuple[str, ...] = PACKAGES) -> dict[str, Path]:
    """Every module of ``packages`` under ``root``, by dotted name."""
    return {module_name(p, root): p for pkg in packages for p in sorted((root / pkg).rglob("*.py"))}


def _absolute(node: ast.ImportFrom, module: str, is_package: bool) -> str:
    """The module a ``from`` import names, with relative imports resolved against ``module``."""
    if not node.level:
        return node.module or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - node.level + 1]
    return ".".join(base + ([node.module] if node.module else []))


def imported_modules(source: str, module: str, known: Mapping[str, Path], is_package: bool = False) -> set[str]:
    """The project modules ``source`` (the text of ``module``) imports anywhere in its body."""
    found = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            target = _absolute(node, module, is_package)
            names = [f"{target}.{a.name}" if f"{target}.{a.name}" in known else target for a in node.names]
        else:
            continue
        for name in names:
            while name and name not in known:  # `import a.b.c` of a name that is an attribute: its module
                name = name.rpartition(".")[0]
            if name:
                found.add(name)
    return found


def import_graph(modules: Mapping[str, Path]) -> dict[str, set[str]]:
    """Module -> the project modules it imports."""
    return {
        name: imported_modules(path.read_text(), name, modules, path.name == "__init__.py")
        for name, path in modules.items()
    }


def strongly_connected(graph: Mapping[str, set[str]]) -> Iterator[list[str]]:
    """Tarjan's strongly connected components of ``graph`` (iterative, so deep graphs do not recurse)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                yield sorted(component)


def cycle_path(graph: Mapping[str, set[str]], component: list[str]) -> list[str]:
    """One closed import path through ``component``, starting and ending at its first module."""
    members, start = set(component), component[0]
    paths = {start: [start]}
    frontier = [start]
    while frontier:
        node = frontier.pop(0)
        for child in sorted(graph[node] & members):
            if child == start:
                return paths[node] + [start]
            if child not in paths:
                paths[child] = paths[node] + [child]
                frontier.append(child)
    return component


def import_cycles(graph: Mapping[str, set[str]]) -> list[list[str]]:
    """Every import cycle of ``graph``, each as a closed path ``a -> b -> ... -> a``."""
    return [
        cycle_path(graph, component)
        for component in strongly_connected(graph)
        if len(component) > 1 or component[0] in graph[component[0]]
    ]


def test_no_import_cycle() -> None:
    cycles = import_cycles(import_graph(project_modules()))
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def folder_graph(modules: Mapping[str, Path], graph: Mapping[str, set[str]]) -> dict[str, set[str]]:
    """Folder (subpackage) -> the folders its modules import, between folders of which neither holds the other
    (a subpackage may use its parent's modules, and a package its subpackages) below the top-level packages."""

    def folder(name: str) -> str:
        return name if modules[name].name == "__init__.py" else name.rpartition(".")[0]

    def nested(a: str, b: str) -> bool:
        return a == b or a.startswith(b + ".") or b.startswith(a + ".")

    folders: dict[str, set[str]] = {folder(name): set() for name in modules if "." in folder(name)}
    for name, targets in graph.items():
        for target in targets:
            a, b = folder(name), folder(target)
            if a in folders and b in folders and not nested(a, b):
                folders[a].add(b)
    return folders


def test_no_import_cycle_between_folders() -> None:
    modules = project_modules()
    cycles = import_cycles(folder_graph(modules, import_graph(modules)))
    assert not cycles, "folders importing each other:\n" + "\n".join(" -> ".join(c) for c in cycles)


#: Which top-level packages each may import: shared is the contract, simgen and learner never meet.
LAYERS = {"shared": {"shared"}, "simgen": {"shared", "simgen"}, "learner": {"shared", "learner"}}


def test_layers() -> None:
    graph = import_graph(project_modules())
    crossing = [
        f"{module} -> {target}"
        for module, targets in graph.items()
        if module.split(".")[0] in LAYERS
        for target in targets
        if target.split(".")[0] not in LAYERS[module.split(".")[0]]
    ]
    assert not crossing, "imports across the layers:\n" + "\n".join(crossing)


def test_graph_sees_every_package() -> None:
    graph = import_graph(project_modules())
    assert {name.split(".")[0] for name in graph} == set(PACKAGES)
    assert "shared.errors" in graph["learner.train.trainer"]


def _write_package(root: Path, files: dict[str, str]) -> dict[str, Path]:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return {module_name(p, root): p for p in sorted(root.rglob("*.py"))}


@pytest.mark.parametrize(
    "b_source",
    [
        "from pkg.a import f\n",
        "def g():\n    from pkg.a import f\n    return f\n",
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg import a\n",
        "from . import a\n",
        "import pkg.a.f\n",
    ],
    ids=["module-level", "function-level", "type-checking", "relative", "attribute-path"],
)
def test_cycle_is_found(tmp_path: Path, b_source: str) -> None:
    modules = _write_package(
        tmp_path,
        {"pkg/__init__.py": "", "pkg/a.py": "from pkg.b import g\ndef f():\n    pass\n", "pkg/b.py": b_source},
    )
    assert import_cycles(import_graph(modules)) == [["pkg.a", "pkg.b", "pkg.a"]]


def test_acyclic_package_passes(tmp_path: Path) -> None:
    modules = _write_package(
        tmp_path,
        {"pkg/__init__.py": "from pkg.a import f\n", "pkg/a.py": "import os\nfrom pkg import b\n", "pkg/b.py": ""},
    )
    graph = import_graph(modules)
    assert graph == {"pkg": {"pkg.a"}, "pkg.a": {"pkg.b"}, "pkg.b": set()}
    assert import_cycles(graph) == []

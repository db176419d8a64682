"""The curated top levels of simgen and learner: every listed name resolves, lazily, to its defining module."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest


@pytest.mark.parametrize("package", ["simgen", "learner"])
def test_every_public_name_resolves(package: str) -> None:
    module = importlib.import_module(package)
    assert set(module.__all__) == set(module._EXPORTS) and len(module.__all__) == len(set(module.__all__))
    for name in module.__all__:
        value = getattr(module, name)
        source = importlib.import_module(module._EXPORTS[name])
        assert value is getattr(source, name), name
    assert set(module.__all__) <= set(dir(module))
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        module.nothing  # noqa: B018


@pytest.mark.parametrize(("package", "heavy"), [("simgen", ("numba", "dask", "zarr")), ("learner", ("torch",))])
def test_import_is_lazy(package: str, heavy: tuple[str, ...]) -> None:
    code = f"import sys, {package}; print(sorted(m for m in {heavy!r} if m in sys.modules))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]"


def test_subpackages_keep_their_names() -> None:
    """A top-level name never shadows a subpackage (``simgen.store`` stays the package)."""
    import simgen
    import simgen.store

    assert simgen.store.__name__ == "simgen.store"
    for package in ("simgen", "learner"):
        module = importlib.import_module(package)
        for name in module.__all__:
            assert importlib.util.find_spec(f"{package}.{name}") is None, f"{package}.{name} is a module"

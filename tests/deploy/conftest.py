"""The deploy files as data: the commands the compose file runs, with its defaults filled in."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml  # PyYAML comes with dask

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
COMPOSE = DEPLOY / "docker" / "compose.yaml"

_DEFAULT = re.compile(r"\$\{(\w+)(?::?-([^}]*))?\}")


def interpolate(text: str) -> str:
    """Fill ``${VAR:-default}`` as compose does with no such variable set (``${VAR}`` -> "")."""
    return _DEFAULT.sub(lambda m: m.group(2) or "", text)


def with_options(argv: list[str], **options: str) -> list[str]:
    """``argv`` with the values of ``--name`` options replaced (``dashboard_address`` -> ``--dashboard-address``)."""
    out = list(argv)
    for name, value in options.items():
        flag = "--" + name.replace("_", "-")
        out[out.index(flag) + 1] = value
    return out


@pytest.fixture(scope="session")
def compose() -> dict:
    """The parsed compose file."""
    return yaml.safe_load(COMPOSE.read_text())


@pytest.fixture(scope="session")
def compose_commands(compose) -> dict[str, list[str]]:
    """Service name -> its command, defaults interpolated."""
    return {name: [interpolate(str(a)) for a in svc["command"]] for name, svc in compose["services"].items()}


@pytest.fixture(name="with_options", scope="session")
def with_options_fixture():
    """The :func:`with_options` helper."""
    return with_options

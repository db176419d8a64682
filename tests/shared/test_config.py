"""Strict TOML -> dataclass loading."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import pytest

from shared.config import from_mapping, load_toml, to_mapping
from shared.errors import ConfigError, TissueError
from shared.tissue import Material, ScarSpec, TissueSpec


@dataclass(frozen=True)
class Inner:
    x: float = 1.0
    mode: Literal["a", "b"] = "a"


@dataclass(frozen=True)
class Outer:
    name: str = "n"
    count: int = 1
    flag: bool = False
    inner: Inner = field(default_factory=Inner)
    values: tuple[float, ...] = ()
    centre: tuple[float, float, float] | None = None


def test_nested_values_and_defaults():
    cfg = from_mapping(Outer, {"count": 3, "inner": {"x": 2, "mode": "b"}, "values": [1, 2.5], "centre": [0, 1, 2]})
    assert cfg == Outer(count=3, inner=Inner(2.0, "b"), values=(1.0, 2.5), centre=(0.0, 1.0, 2.0))
    assert isinstance(cfg.inner.x, float)


@pytest.mark.parametrize(
    "data, match",
    [
        ({"colour": 1}, r"unknown key\(s\) \['colour'\]"),
        ({"inner": {"y": 1}}, r"inner: unknown key"),
        ({"count": 1.5}, "count: expected an integer"),
        ({"count": True}, "count: expected an integer"),
        ({"flag": 1}, "flag: expected true/false"),
        ({"inner": {"mode": "c"}}, r"inner.mode: 'c' is not one of"),
        ({"centre": [0, 1]}, "centre"),
        ({"inner": 3}, "inner: expected a table"),
        ({"name": 5}, "name: expected a string"),
        ({"inner": {"x": float("nan")}}, "inner.x: expected a finite number, got nan"),
        ({"values": [1.0, float("-inf")]}, r"values\[1\]: expected a finite number, got -inf"),
    ],
)
def test_bad_values_name_the_key(data, match):
    with pytest.raises(ConfigError, match=match):
        from_mapping(Outer, data)


def test_domain_errors_pass_through_and_round_trip():
    with pytest.raises(TissueError, match="excitability"):
        from_mapping(TissueSpec, {"healthy": {"a": 0.9}})
    spec = TissueSpec("s", scars=(ScarSpec("sphere", node=3, radius=5.0, core=Material(0.45, 0.2)),))
    assert from_mapping(TissueSpec, to_mapping(spec)) == spec


def test_load_toml_errors(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_toml(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("a = [1,\n")
    with pytest.raises(ConfigError, match="invalid TOML"):
        load_toml(bad)
    good = tmp_path / "good.toml"
    good.write_text('name = "x"\ncount = 2\n')
    assert from_mapping(Outer, load_toml(good)).count == 2

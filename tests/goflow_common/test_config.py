"""goflow_common.config: configs from defaults, mappings and overrides, and back to JSON data."""

from dataclasses import dataclass, field
from pathlib import Path

import pytest

from goflow_common.config import config_to_dict, config_with_overrides
from goflow_common.errors import UnknownOptionError


@dataclass
class Inner:
    lr: float = 1e-3
    sizes: tuple[int, ...] = (64, 64)


@dataclass
class Outer:
    name: str = "a"
    out: Path | None = None
    inner: Inner = field(default_factory=Inner)


def test_mapping_instance_and_overrides():
    c = config_with_overrides(Outer, {"name": "b", "inner": {"lr": 0.1}}, {"out": Path("x")})
    assert c == Outer("b", Path("x"), Inner(lr=0.1))
    assert config_with_overrides(Outer, c, {"name": "c"}).inner.lr == 0.1
    assert config_with_overrides(Outer) == Outer()


def test_unknown_options_are_named():
    with pytest.raises(
        UnknownOptionError, match=r"Outer: unknown option\(s\) \['nme'\]; known: \['inner', 'name', 'out'\]"
    ):
        config_with_overrides(Outer, {"nme": 1})
    with pytest.raises(ValueError, match=r"Outer.inner: unknown option\(s\) \['l'\]"):
        config_with_overrides(Outer, {"inner": {"l": 1}})
    with pytest.raises(TypeError):  # also a TypeError, as Python's own unknown keyword
        config_with_overrides(Outer, None, {"bogus": 1})


def test_round_trip_through_json_data():
    c = Outer("b", Path("runs/x"), Inner(0.5, (8,)))
    d = config_to_dict(c)
    assert d == {"name": "b", "out": "runs/x", "inner": {"lr": 0.5, "sizes": [8]}}
    back = config_with_overrides(Outer, d)
    assert back.inner == Inner(0.5, [8]) and back.out == "runs/x"

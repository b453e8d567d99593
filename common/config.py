"""Configuration dataclasses from defaults, mappings (JSON, command line) and keyword overrides,
and back to plain JSON data: the one helper every config in goflow goes through.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

from common.errors import InputError, UnknownOptionError

__all__ = ["config_with_overrides", "config_to_dict"]

C = TypeVar("C")


def _nested_types(config_type: type) -> dict[str, type]:
    """Fields of `config_type` whose declared type is itself a dataclass (optionally `| None`)."""
    try:
        hints = typing.get_type_hints(config_type)
    except Exception:  # unresolvable annotations: no nested conversion
        return {}
    out = {}
    for name, hint in hints.items():
        candidates = [hint, *typing.get_args(hint)]
        for c in candidates:
            if isinstance(c, type) and dataclasses.is_dataclass(c):
                out[name] = c
                break
    return out


def config_with_overrides(config_type: type[C], config: C | Mapping[str, Any] | None = None,
                          overrides: Mapping[str, Any] | None = None, owner: str | None = None) -> C:
    """A `config_type` dataclass built from `config` and then `overrides`.

    Arguments:
        config_type: the dataclass type.
        config: None (the type's defaults), an instance, or a mapping of field values (e.g. read
            from JSON or the command line); nested dataclass fields may be given as mappings too.
        overrides: field values applied last.
        owner: the name used in error messages (default: the type's name).

    Returns:
        A new instance (its `__post_init__` validates the values).

    Raises:
        UnknownOptionError: a key is not a field (the message lists the known fields).
        InputError: `config` is neither None, an instance nor a mapping.
    """
    owner = owner or config_type.__name__
    if config is None:
        values: dict[str, Any] = {}
    elif isinstance(config, config_type):
        values = {f.name: getattr(config, f.name) for f in dataclasses.fields(config_type) if f.init}
    elif isinstance(config, Mapping):
        values = dict(config)
    else:
        raise InputError(f"{owner}: config = {config!r}; expected None, a mapping or a {config_type.__name__}")
    values.update(overrides or {})
    known = {f.name for f in dataclasses.fields(config_type) if f.init}
    unknown = sorted(set(values) - known)
    if unknown:
        raise UnknownOptionError(f"{owner}: unknown option(s) {unknown}; known: {sorted(known)}")
    for name, sub in _nested_types(config_type).items():
        if isinstance(values.get(name), Mapping):
            values[name] = config_with_overrides(sub, values[name], owner=f"{owner}.{name}")
    return config_type(**values)


def config_to_dict(config: Any) -> Any:
    """Plain JSON data of a (nested) dataclass: Paths as strings, tuples as lists; the inverse of
    `config_with_overrides(type(config), config_to_dict(config))`."""
    if dataclasses.is_dataclass(config) and not isinstance(config, type):
        return {f.name: config_to_dict(getattr(config, f.name)) for f in dataclasses.fields(config)}
    if isinstance(config, Mapping):
        return {str(k): config_to_dict(v) for k, v in config.items()}
    if isinstance(config, (list, tuple)):
        return [config_to_dict(v) for v in config]
    if isinstance(config, Path):
        return str(config)
    return config

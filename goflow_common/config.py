"""Configuration dataclasses from defaults, mappings (JSON, command line) and keyword overrides,
and back to plain JSON data: the one helper every config in goflow goes through.
"""

from __future__ import annotations

import dataclasses
import json
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, TypeVar

from goflow_common.errors import InputError, UnknownOptionError

__all__ = ["config_with_overrides", "config_to_dict", "key_values", "parse_value"]

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


def config_with_overrides(
    config_type: type[C],
    config: C | Mapping[str, Any] | None = None,
    overrides: Mapping[str, Any] | None = None,
    owner: str | None = None,
) -> C:
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


_NON_FINITE = {"nan", "inf", "infinity"}


def parse_value(text: str, what: str) -> Any:
    """A value given on the command line: strict JSON when it is JSON (numbers, true, false, null,
    lists, objects), else the string itself. NaN and Infinity (in any spelling) are refused with an
    InputError naming `what`."""

    def refuse(constant: str) -> Any:
        raise InputError(f"{what}: {constant} is not allowed; expected a finite number")

    if text.strip().lower().lstrip("+-") in _NON_FINITE:
        refuse(text.strip())
    try:
        return json.loads(text, parse_constant=refuse)
    except json.JSONDecodeError:
        return text


def key_values(pairs: Iterable[str] | None, flag: str) -> dict[str, Any]:
    """["a=1", "b=x"] -> {"a": 1, "b": "x"}: the one parser of every KEY=VALUE flag (values by
    `parse_value`); InputError for a pair without "=" or a key given twice."""
    out: dict[str, Any] = {}
    for pair in pairs or []:
        key, eq, value = pair.partition("=")
        if not eq or not key:
            raise InputError(f"{flag} {pair!r}: expected KEY=VALUE")
        if key in out:
            raise InputError(f"{flag} {key}: given twice")
        out[key] = parse_value(value, f"{flag} {pair}")
    return out

"""Argument checks shared by every package: each returns the checked value or raises InputError
with a message of the form "NAME = VALUE; expected ...".
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from goflow_common.errors import InputError

__all__ = ["check_int", "check_number", "check_choice", "check_layer_sizes", "check_finite_array", "InputErrorParser"]


def check_int(value: Any, name: str, minimum: int | None = None) -> int:
    """`value` as an int; InputError unless it is an integer (not a bool) >= `minimum`."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise InputError(f"{name} = {value!r}; expected an integer" + (f" >= {minimum}" if minimum is not None else ""))
    if minimum is not None and value < minimum:
        raise InputError(f"{name} = {value!r}; expected an integer >= {minimum}")
    return int(value)


def check_number(
    value: Any,
    name: str,
    low: float | None = None,
    high: float | None = None,
    *,
    low_open: bool = False,
    high_open: bool = False,
    allow_inf: bool = False,
) -> float:
    """`value` as a float; InputError unless it is a real number (not a bool), finite unless
    `allow_inf`, and inside [low, high] (an open end where `low_open` / `high_open`)."""
    lb = "(" if low_open or low is None else "["
    ub = ")" if high_open or high is None else "]"
    bounds = (
        ""
        if low is None and high is None
        else (f" in {lb}{'-inf' if low is None else f'{low:g}'}, {'inf' if high is None else f'{high:g}'}{ub}")
    )
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"{name} = {value!r}; expected a number{bounds}")
    v = float(value)
    if math.isnan(v) or (math.isinf(v) and not allow_inf):
        raise InputError(f"{name} = {value!r}; expected a finite number{bounds}")
    if low is not None and (v <= low if low_open else v < low):
        raise InputError(f"{name} = {value!r}; expected a number{bounds}")
    if high is not None and (v >= high if high_open else v > high):
        raise InputError(f"{name} = {value!r}; expected a number{bounds}")
    return v


def check_choice(value: Any, choices: Iterable[Any], name: str) -> Any:
    """`value` if it is one of `choices`; InputError listing them otherwise."""
    options = list(choices)
    if value not in options:
        raise InputError(f"{name} = {value!r}; expected one of {options}")
    return value


def check_layer_sizes(value: Any, name: str) -> tuple[int, ...]:
    """`value` (a list or tuple) as a tuple of ints, the layer sizes of an MLP; InputError naming
    `name` unless it holds at least one entry and every entry is an integer >= 1."""
    sizes = tuple(value) if isinstance(value, (list, tuple)) else ()
    if not sizes:
        raise InputError(f"{name} = {value!r}; expected a non-empty list of layer sizes")
    return tuple(check_int(h, f"{name} entry", 1) for h in sizes)


def check_finite_array(
    value: ArrayLike,
    name: str,
    shape: Sequence[int | None] | None = None,
    low: float | None = None,
    high: float | None = None,
) -> NDArray[np.float64]:
    """`value` as a float64 array; InputError unless it is numeric, finite, of `shape` (None entries
    match any length) and inside [low, high] elementwise."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} = {value!r}; expected an array of numbers") from exc
    if shape is not None and (
        arr.ndim != len(shape) or any(s is not None and a != s for a, s in zip(arr.shape, shape))
    ):
        want = "(" + ", ".join("n" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
        raise InputError(f"{name} has shape {arr.shape}; expected {want}")
    if not np.all(np.isfinite(arr)):
        bad = np.flatnonzero(~np.isfinite(arr.ravel()))
        raise InputError(
            f"{name} must be finite; {len(bad)} entries are not (first: flat index {bad[0]} = {arr.ravel()[bad[0]]})"
        )
    for bound, outside, word in (
        (low, arr < (low if low is not None else 0), "below"),
        (high, arr > (high if high is not None else 0), "above"),
    ):
        if bound is not None and outside.any():
            i = int(np.flatnonzero(outside.ravel())[0])
            raise InputError(
                f"{name}: {int(outside.sum())} entries are {word} {bound:g} (first: flat index "
                f"{i} = {arr.ravel()[i]:g}); expected values in [{low if low is not None else '-inf'}, "
                f"{high if high is not None else 'inf'}]"
            )
    return arr


class InputErrorParser(argparse.ArgumentParser):
    """An ArgumentParser whose bad flags raise InputError (one line, caught with every other input
    error) instead of printing the usage and exiting."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise InputError(message)

"""Named, bounded simulator parameters xi with units, and the box they live in.

Every environment draws its per-episode parameters xi from a `ParamSpace`; every sampler
(NoDR, FullDR and the learned ones) is defined on one; every checkpoint stores the one it was
trained on (`to_dict`) so that loading it into an environment with a different box fails loudly.

Array conventions: a single xi has shape (d,), a batch has shape (n, d); the columns follow the
order of `ParamSpace.params`. Values are in the parameters' own units (SI, radians).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["Param", "ParamSpace"]

_PARAM_KEYS = ("name", "low", "high", "unit", "nominal")


def _finite_float(value: Any, what: str) -> float:
    """Return value as a float, raising ValueError unless it is a finite real number."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{what} must be a finite real number, got {value!r}")
    out = float(value)
    if not math.isfinite(out):
        raise ValueError(f"{what} must be finite, got {out}")
    return out


@dataclass(frozen=True)
class Param:
    """One named scalar parameter on the closed interval [low, high], in `unit`."""

    name: str
    low: float
    high: float
    unit: str
    nominal: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"Param name must be a non-empty string, got {self.name!r}")
        if not isinstance(self.unit, str):
            raise ValueError(
                f"Param {self.name!r}: unit must be a string (use '1' if dimensionless), got {self.unit!r}"
            )
        low = _finite_float(self.low, f"Param {self.name!r}: low")
        high = _finite_float(self.high, f"Param {self.name!r}: high")
        if not low < high:
            raise ValueError(f"Param {self.name!r}: need low < high, got low={low:g}, high={high:g} {self.unit}")
        nominal = (
            0.5 * (low + high) if self.nominal is None else _finite_float(self.nominal, f"Param {self.name!r}: nominal")
        )
        if not low <= nominal <= high:
            raise ValueError(
                f"Param {self.name!r}: nominal {nominal:g} {self.unit} is outside its bounds [{low:g}, {high:g}] {self.unit}"
            )
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)
        object.__setattr__(self, "nominal", nominal)

    @property
    def width(self) -> float:
        """Length of the interval, high - low."""
        return self.high - self.low

    def bounds_text(self) -> str:
        """The bounds as text for error messages, e.g. '[-1, 1] m'."""
        return f"[{self.low:g}, {self.high:g}] {self.unit}".rstrip()

    def to_dict(self) -> dict[str, Any]:
        """A JSON-serializable dict of the fields (nominal included)."""
        return {"name": self.name, "low": self.low, "high": self.high, "unit": self.unit, "nominal": self.nominal}


@dataclass(frozen=True)
class ParamSpace:
    """An ordered box of named parameters; normalizes xi to and from the unit box [0, 1]^d."""

    params: tuple[Param, ...] = field()

    def __post_init__(self) -> None:
        params = tuple(self.params)
        if not params:
            raise ValueError("ParamSpace needs at least one Param")
        for p in params:
            if not isinstance(p, Param):
                raise ValueError(f"ParamSpace takes Param objects, got {type(p).__name__}: {p!r}")
        names = [p.name for p in params]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise ValueError(f"ParamSpace has duplicate parameter names: {dupes}")
        object.__setattr__(self, "params", params)

    # -- shape and box -------------------------------------------------------------------------

    @property
    def dim(self) -> int:
        """Number of parameters d."""
        return len(self.params)

    @property
    def names(self) -> tuple[str, ...]:
        """Parameter names in column order."""
        return tuple(p.name for p in self.params)

    @property
    def units(self) -> tuple[str, ...]:
        """Parameter units in column order."""
        return tuple(p.unit for p in self.params)

    @property
    def low(self) -> NDArray[np.float64]:
        """Lower bounds, shape (d,) (a fresh array each call)."""
        return np.array([p.low for p in self.params], dtype=np.float64)

    @property
    def high(self) -> NDArray[np.float64]:
        """Upper bounds, shape (d,) (a fresh array each call)."""
        return np.array([p.high for p in self.params], dtype=np.float64)

    def nominal(self) -> NDArray[np.float64]:
        """Nominal values, shape (d,) (the box centre unless a Param sets its own)."""
        return np.array([p.nominal for p in self.params], dtype=np.float64)

    def center(self) -> NDArray[np.float64]:
        """Box centre, shape (d,)."""
        return 0.5 * (self.low + self.high)

    def volume(self) -> float:
        """Lebesgue volume of the box in the product of the parameters' units."""
        return float(np.prod(self.high - self.low))

    # -- checks --------------------------------------------------------------------------------

    def _shape_error(self, shape: tuple[int, ...], what: str) -> ValueError:
        """The ValueError for an array of the wrong shape."""
        return ValueError(
            f"{what} has shape {shape}, expected shape ({self.dim},) or (n, {self.dim}) for parameters {self.names}"
        )

    def _shaped(self, xi: ArrayLike, what: str) -> tuple[NDArray[np.float64], bool]:
        """xi as a float (n, d) array and whether it was a single (d,) point; only the shape is checked."""
        arr = np.asarray(xi, dtype=np.float64)
        if arr.ndim == 1 and arr.shape[0] == self.dim:
            return arr[None, :], True
        if arr.ndim == 2 and arr.shape[1] == self.dim:
            return arr, False
        raise self._shape_error(arr.shape, what)

    def as_batch(self, xi: ArrayLike, what: str = "xi") -> NDArray[np.float64]:
        """xi as a finite float (n, d) array (a (d,) input becomes (1, d)); bounds are not checked."""
        batch, _ = self._shaped(xi, what)
        bad = ~np.isfinite(batch)
        if bad.any():
            row, col = map(int, np.argwhere(bad)[0])
            p = self.params[col]
            raise ValueError(
                f"{what}: parameter {p.name!r} is {batch[row, col]} (row {row}); every value must be finite, "
                f"within {p.bounds_text()}"
            )
        return batch

    def contains(self, xi: ArrayLike) -> bool | NDArray[np.bool_]:
        """Whether xi lies in the closed box (non-finite values do not): a bool for (d,), a bool array (n,) for (n, d)."""
        batch, single = self._shaped(xi, "xi")
        inside = np.all((batch >= self.low) & (batch <= self.high), axis=1)  # NaN compares False
        return bool(inside[0]) if single else inside

    def validate(self, xi: ArrayLike, what: str = "xi") -> NDArray[np.float64]:
        """Return xi as a float64 copy of the same shape, or raise ValueError naming what is wrong."""
        arr = np.asarray(xi, dtype=np.float64)
        batch = self.as_batch(arr, what)  # shape and finiteness
        low, high = self.low, self.high
        outside = (batch < low) | (batch > high)
        if outside.any():
            rows, cols = np.nonzero(outside)
            row, col = int(rows[0]), int(cols[0])
            p = self.params[col]
            where = f" (row {row}; {len(rows)} value(s) outside in all)" if arr.ndim == 2 else ""
            raise ValueError(
                f"{what}: parameter {p.name!r} = {batch[row, col]:g} {p.unit} is outside its bounds {p.bounds_text()}{where}"
            )
        return batch.copy() if arr.ndim == 2 else batch[0].copy()

    # -- unit box ------------------------------------------------------------------------------

    def normalize(self, xi: ArrayLike) -> NDArray[np.float64]:
        """Map xi affinely to the unit box: low -> 0, high -> 1 (same shape as xi; not clipped)."""
        arr = np.asarray(xi, dtype=np.float64)
        u = (self.as_batch(arr) - self.low) / (self.high - self.low)
        return u if arr.ndim == 2 else u[0]

    def denormalize(self, u: ArrayLike) -> NDArray[np.float64]:
        """Inverse of `normalize`: unit-box coordinates to parameter units (same shape as u)."""
        arr = np.asarray(u, dtype=np.float64)
        xi = self.low + self.as_batch(arr, "u") * (self.high - self.low)
        return xi if arr.ndim == 2 else xi[0]

    # -- checkpoints ---------------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """A JSON-serializable dict; `ParamSpace.from_dict(s.to_dict()) == s`."""
        return {"params": [p.to_dict() for p in self.params]}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> ParamSpace:
        """Rebuild a ParamSpace from `to_dict` output, raising ValueError if it is malformed."""
        if not isinstance(d, Mapping) or "params" not in d:
            raise ValueError(
                f"ParamSpace dict must have a 'params' list, got keys {list(d) if isinstance(d, Mapping) else d!r}"
            )
        params = []
        for i, entry in enumerate(d["params"]):
            if not isinstance(entry, Mapping):
                raise ValueError(f"ParamSpace dict: params[{i}] must be a dict, got {entry!r}")
            missing = [k for k in _PARAM_KEYS[:4] if k not in entry]
            unknown = [k for k in entry if k not in _PARAM_KEYS]
            if missing or unknown:
                raise ValueError(
                    f"ParamSpace dict: params[{i}] is missing {missing} / has unknown keys {unknown}; "
                    f"expected keys {list(_PARAM_KEYS)}"
                )
            params.append(Param(**{k: entry[k] for k in _PARAM_KEYS if k in entry}))
        return cls(tuple(params))

    def diff(self, other: ParamSpace) -> list[str]:
        """Human-readable differences from `other` (empty when equal), for mismatch errors."""
        if self.names != other.names:
            return [f"parameter names differ: {self.names} vs {other.names}"]
        out = []
        for a, b in zip(self.params, other.params):
            for key in ("low", "high", "unit", "nominal"):
                va, vb = getattr(a, key), getattr(b, key)
                if va != vb:
                    out.append(f"parameter {a.name!r}: {key} {va!r} vs {vb!r}")
        return out

    def __str__(self) -> str:
        """One line per parameter: name in [low, high] unit."""
        return "ParamSpace(" + ", ".join(f"{p.name} in {p.bounds_text()}" for p in self.params) + ")"

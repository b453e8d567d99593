"""The exception families goflow raises, so that callers (the CLI above all) can catch a family.

Every class subclasses a builtin, so code that catches ValueError or RuntimeError keeps working.
"""

from __future__ import annotations

__all__ = [
    "GoflowError",
    "InputError",
    "UnknownOptionError",
    "FileFormatError",
    "OutputPathError",
    "RunFolderBusyError",
    "SimulationError",
    "ClusterError",
    "GridError",
]


class GoflowError(Exception):
    """Base of every error goflow raises on purpose."""


class InputError(GoflowError, ValueError):
    """A value given by the user is wrong; the message names the value and what was expected."""


class UnknownOptionError(InputError, TypeError):
    """An option (a config field, a keyword) that does not exist; the message lists the known ones.

    It is also a TypeError, as Python raises for an unknown keyword argument."""


class FileFormatError(InputError):
    """A file exists but is not what it should be (empty, truncated, foreign or unsafe)."""


class OutputPathError(InputError):
    """An output path cannot be written (checked before the work starts)."""


class RunFolderBusyError(GoflowError, RuntimeError):
    """Another process holds the run folder's lock."""


class SimulationError(GoflowError, RuntimeError):
    """A physics step failed (solver divergence, non-finite state): the episode cannot go on."""


class ClusterError(GoflowError, RuntimeError):
    """The Ray cluster asked for cannot be used: the `ray` package is missing, or no cluster answers
    at the address; the message says which and how to fix it."""


class GridError(GoflowError, RuntimeError):
    """Some jobs of a grid failed after the others had finished; `failures` maps each failed job's
    name to its one-line message and `results` holds every job's result (None where it failed)."""

    def __init__(self, message: str, failures: dict[str, str] | None = None, results: list | None = None) -> None:
        super().__init__(message)
        self.failures = dict(failures or {})
        self.results = list(results or [])

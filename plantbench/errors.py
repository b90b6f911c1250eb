"""Exceptions. The library raises; only the CLI prints and exits.

:class:`InputError` is a user mistake (bad file, unknown name, invalid value): the CLI prints its message on one
line and exits with code 2, with no traceback unless ``--debug``.
"""

from __future__ import annotations

__all__ = ["PlantbenchError", "InputError", "UnknownNameError", "NotAvailableError"]


class PlantbenchError(Exception):
    """Base class of every error plantbench raises on purpose."""


class InputError(PlantbenchError, ValueError):
    """Invalid user input. ``path`` and ``field`` name where, when known."""

    def __init__(self, message: str, *, path: object = None, field: str | None = None) -> None:
        self.path = path
        self.field = field
        where = ""
        if path is not None:
            where = f"{path}: "
        if field:
            where += f"{field}: "
        super().__init__(where + message)


class UnknownNameError(InputError, KeyError):
    """A name that is not registered. The message carries "did you mean" and the available names."""

    def __str__(self) -> str:  # KeyError would quote the message
        return self.args[0]


class NotAvailableError(PlantbenchError):
    """A stage that is not implemented in this version."""

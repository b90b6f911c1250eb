"""The ``plantbench`` command line, one module per command group (the way pip's ``_internal/commands`` and DVC's
``commands`` are laid out), each a thin layer over the library.

Only these modules print or exit. A user mistake (InputError: unknown name, malformed file, invalid value) prints
one line and exits 2; a method or stage that fails exits 1 with a one-line message; ``--debug`` shows tracebacks.
"""

from __future__ import annotations

import importlib
import sys

import typer

from plantbench.commands._app import _state, app
from plantbench.errors import InputError, NotAvailableError, PlantbenchError

__all__ = ["app", "main"]

GROUPS = ("case", "run", "gate", "dataset", "imports", "qsm", "listing")
"""The command modules, in the order ``plantbench --help`` lists their commands."""

for _module in GROUPS:
    importlib.import_module(f"plantbench.commands.{_module}")


def main(argv: list[str] | None = None) -> int:
    """Console entry point: run the CLI and map errors to exit codes (2 user error, 1 not available / failure)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    _state["debug"] = "--debug" in argv
    try:
        rc = app(argv, standalone_mode=False)  # returns the code of a typer.Exit in non-standalone mode
        if isinstance(rc, int):
            return rc
    except typer.Exit as exc:
        return exc.exit_code
    except SystemExit as exc:
        return int(exc.code or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - the CLI maps every error to one line
        if _state["debug"]:
            raise
        if type(exc).__name__ == "Abort":  # Ctrl-C at a prompt
            return 130
        if hasattr(exc, "show") and hasattr(exc, "exit_code"):  # click-style usage errors (typer vendors click)
            exc.show()
            return int(exc.exit_code)
        if isinstance(exc, InputError):
            print(f"error: {exc}", file=sys.stderr)
            return 2
        if isinstance(exc, NotAvailableError):
            print(str(exc), file=sys.stderr)
            return 1
        if isinstance(exc, PlantbenchError):
            print(f"error: {exc}", file=sys.stderr)
            return 1
        print(f"internal error: {type(exc).__name__}: {exc} (run with --debug for the traceback)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

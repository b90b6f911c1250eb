"""The ``plantbench`` command (entry point ``plantbench.cli:main``); the commands live in :mod:`plantbench.commands`,
one module per command group."""

from __future__ import annotations

import sys

from plantbench.commands import app, main

__all__ = ["app", "main"]

if __name__ == "__main__":
    sys.exit(main())

"""Suite options (``[method_options.NAME]``) to a method's frozen parameter dataclass."""

from __future__ import annotations

import dataclasses

from plantbench.errors import InputError

__all__ = ["params_from_options"]


def params_from_options(cls, options: dict):
    """``cls(**options)`` for a frozen params dataclass; unknown names raise InputError listing the valid ones, and
    list values become tuples where the default is a tuple (TOML has no tuples)."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    bad = sorted(set(options) - set(fields))
    if bad:
        raise InputError(f"unknown option(s) {', '.join(bad)} (valid: {', '.join(sorted(fields))})")
    values = {k: tuple(v) if isinstance(v, list) and isinstance(fields[k].default, tuple) else v
              for k, v in options.items()}
    try:
        return cls(**values)
    except TypeError as exc:
        raise InputError(str(exc)) from None

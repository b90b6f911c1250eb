"""One registry for methods, metrics, species and suites.

A :class:`Registry` maps names to objects, refuses a second registration under the same name, and answers an
unknown name with "did you mean" plus the available names. The method registry also loads third-party methods
from the entry-point group ``plantbench.methods``; the methods shipped in ``reference_impl`` register through
the same group. Species and suites are data files under ``scenes/`` and are discovered from there.
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Iterator
from importlib.metadata import entry_points
from typing import Generic, TypeVar

from plantbench.errors import InputError, UnknownNameError

__all__ = ["Registry", "methods", "metrics", "ENTRY_POINT_GROUP", "did_you_mean"]

T = TypeVar("T")
ENTRY_POINT_GROUP = "plantbench.methods"


def did_you_mean(kind: str, name: str, available: list[str]) -> str:
    close = difflib.get_close_matches(name, available, n=3, cutoff=0.5)
    msg = f"unknown {kind} '{name}'"
    if close:
        msg += f"; did you mean {' or '.join(repr(c) for c in close)}?"
    msg += f" Available: {', '.join(sorted(available)) if available else '(none)'}"
    return msg


class Registry(Generic[T]):
    """Name -> object map that refuses duplicates.

    ``loader`` (optional) is called once, on first lookup, to populate lazily (entry points, data folders).
    """

    def __init__(self, kind: str, loader: Callable[[Registry[T]], None] | None = None) -> None:
        self.kind = kind
        self._items: dict[str, T] = {}
        self._loader = loader
        self._loaded = loader is None
        self._errors: dict[str, str] = {}

    def register(self, name: str, obj: T | None = None):
        """Register ``obj`` under ``name``; without ``obj``, return a decorator."""
        if obj is None:
            def deco(o: T) -> T:
                self.register(name, o)
                return o

            return deco
        if not name or not isinstance(name, str):
            raise InputError(f"{self.kind} name must be a non-empty string, got {name!r}")
        if name in self._items:
            raise InputError(f"{self.kind} '{name}' is already registered")
        self._items[name] = obj
        return obj

    def _ensure_loaded(self) -> None:
        if not self._loaded:
            self._loaded = True
            assert self._loader is not None
            self._loader(self)

    def get(self, name: str) -> T:
        self._ensure_loaded()
        try:
            return self._items[name]
        except KeyError:
            if name in self._errors:
                raise InputError(f"{self.kind} '{name}' failed to load: {self._errors[name]}") from None
            raise UnknownNameError(did_you_mean(self.kind, name, self.names())) from None

    def names(self) -> list[str]:
        self._ensure_loaded()
        return sorted(self._items)

    def items(self) -> Iterator[tuple[str, T]]:
        self._ensure_loaded()
        return iter(sorted(self._items.items()))

    def reset(self) -> None:
        """Forget everything; the loader runs again on the next lookup (e.g. after PLANTBENCH_SCENES changed)."""
        self._items.clear()
        self._errors.clear()
        self._loaded = self._loader is None

    def load_errors(self) -> dict[str, str]:
        """Plugins whose entry point failed to import: name -> error text."""
        self._ensure_loaded()
        return dict(self._errors)

    def __contains__(self, name: str) -> bool:
        self._ensure_loaded()
        return name in self._items


def _load_method_entry_points(reg: Registry) -> None:
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            obj = ep.load()
        except Exception as exc:  # a broken plugin must not take the others down
            reg._errors[ep.name] = f"{type(exc).__name__}: {exc}"
            continue
        method = obj() if isinstance(obj, type) else obj
        if getattr(method, "name", ep.name) != ep.name:
            reg._errors[ep.name] = f"entry point name '{ep.name}' differs from the method's name '{method.name}'"
            continue
        reg.register(ep.name, method)


def _load_metrics(reg: Registry) -> None:
    from plantbench.metrics.info import METRICS

    for name, info in METRICS.items():
        reg.register(name, info)


methods: Registry = Registry("method", _load_method_entry_points)
metrics: Registry = Registry("metric", _load_metrics)

"""What a method can be told: its options, read from the same parameter model that validates them.

A method declares ``options_model``: a frozen dataclass of its parameters (the one its ``check_options`` and
``reconstruct`` build with :func:`plantbench.schemas.params_from_options` or a ``from_options``), or a mapping of
prefix -> dataclass for a method that reads several (guo: its own parameters and the leaf stage's as ``leaf__NAME``);
a field whose default is itself a parameter dataclass is listed as ``GROUP__NAME`` (the mvs stage's
``depth_params__hypotheses``). ``extra_options`` lists the options a method reads itself, beside the model: name ->
(default, one line of meaning). :func:`describe_options` turns both into rows (name, default, unit, meaning) for
``plantbench methods NAME``; :func:`parse_option` reads ``--option NAME=VALUE`` for ``plantbench reconstruct``.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import re
import textwrap
import tomllib
from collections import namedtuple
from typing import Any

from plantbench.errors import InputError

__all__ = ["OptionInfo", "describe_options", "parse_option", "parse_options", "field_docstrings"]


OptionInfo = namedtuple("OptionInfo", "name default unit meaning")
"""One option of a method: its name, default, unit ('-' when it has none) and one line of meaning."""


_UNITS = (  # (pattern on the name, unit), then (pattern on the docstring, unit); first match wins
    (r"_deg$", "deg"), (r"_px$|pixels?$", "px"), (r"_s$|seconds$", "s"), (r"_m$|_cm$", "m"),
)
_DOC_UNITS = (
    (r"\bdegrees?\b", "deg"), (r"\bpixels?\b|\bpx\b", "px"), (r"\bseconds?\b", "s"),
    (r"\bmetres?\b|\bat 20 m\b", "m"), (r"\bfraction\b|\bshare\b", "fraction"),
)


def field_docstrings(cls: type) -> dict[str, str]:
    """Field name -> the string literal that follows its definition in the source of ``cls`` or of the class it
    inherits the field from (the attribute docstring convention of Sphinx and PEP 257); a class whose source cannot
    be read gives none."""
    out: dict[str, str] = {}
    for klass in reversed(cls.__mro__[:-1]):
        out.update(_own_docstrings(klass))
    return out


def _own_docstrings(cls: type) -> dict[str, str]:
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    except (OSError, TypeError, SyntaxError):
        return {}
    body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
    out = {}
    for node, after in zip(body, [*body[1:], None], strict=True):
        if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and isinstance(after, ast.Expr)
                and isinstance(after.value, ast.Constant) and isinstance(after.value.value, str)):
            out[node.target.id] = inspect.cleandoc(after.value.value)
    return out


def _first_sentence(doc: str) -> str:
    text = " ".join(doc.split())
    m = re.search(r"(?<=[a-z0-9)\]'\"])\.\s", text)
    return text[: m.start() + 1] if m else text


def _unit(name: str, doc: str) -> str:
    for pattern, unit in _UNITS:
        if re.search(pattern, name):
            return unit
    first = _first_sentence(doc).lower()
    for pattern, unit in _DOC_UNITS:
        if re.search(pattern, first):
            return unit
    return "-"


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return None


def _rows(cls: type, prefix: str) -> list[OptionInfo]:
    docs = field_docstrings(cls)
    rows = []
    for f in dataclasses.fields(cls):
        default = _default(f)
        if dataclasses.is_dataclass(default) and not isinstance(default, type):
            rows += _rows(type(default), f"{prefix}{f.name}__")
            continue
        doc = docs.get(f.name, "")
        rows.append(OptionInfo(prefix + f.name, default, _unit(f.name, doc), _first_sentence(doc)))
    return rows


def describe_options(method) -> list[OptionInfo]:
    """Every option ``method`` takes, in the order its model defines them, the ``extra_options`` first; [] for a
    method that takes none (or declares no model)."""
    rows = [OptionInfo(name, default, _unit(name, meaning), meaning)
            for name, (default, meaning) in (getattr(method, "extra_options", None) or {}).items()]
    model = getattr(method, "options_model", None)
    models = model if isinstance(model, dict) else ({"": model} if model is not None else {})
    for prefix, cls in models.items():
        rows += _rows(cls, prefix)
    return rows


def parse_option(text: str) -> tuple[str, Any]:
    """``NAME=VALUE`` -> (NAME, VALUE), the value read as a TOML value (``3``, ``0.5``, ``true``, ``[5, 45]``,
    ``"text"``) as a suite's ``[method_options]`` table would hold it, else taken as a plain string (``depth=oracle``).
    """
    name, sep, value = text.partition("=")
    name = name.strip()
    if not sep or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        raise InputError(f"--option takes NAME=VALUE, got {text!r}")
    try:
        return name, tomllib.loads(f"v = {value.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        return name, value.strip()


def parse_options(texts: list[str] | None) -> dict[str, Any]:
    """Every ``--option NAME=VALUE`` of a command line as a dict; a name given twice is an InputError."""
    out: dict[str, Any] = {}
    for text in texts or []:
        name, value = parse_option(text)
        if name in out:
            raise InputError(f"--option {name} given twice")
        out[name] = value
    return out

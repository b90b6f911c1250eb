"""Listings: ``species``, ``suites``, ``methods``, ``metrics``."""

from __future__ import annotations

import sys
from typing import Annotated, Optional

import typer

from plantbench.commands._app import _console, _emit, app
from plantbench.errors import InputError, PlantbenchError


@app.command("species")
def species_cmd(
    stats: Annotated[bool, typer.Option(
        "--stats", help="Grow each species and compare with Guo et al. 2018, Table 2.")] = False,
) -> None:
    """List the species library."""
    from rich.table import Table

    from plantbench.species import load_species, species

    if stats:
        from plantbench.generate import species_stats

        rows = species_stats()
        table = Table("species", "H (m)", "H paper", "|B|", "|B| paper", "l_B (m)", "l_B paper")

        def f(v, spec=".2f"):
            return "-" if v is None else format(v, spec)

        for r in rows:
            table.add_row(
                r["species"], f(r["H"]), f(r.get("H_paper")), f(r["B"], ".0f"), f(r.get("B_paper"), ".0f"),
                f(r["l_B"], ".3f"), f(r.get("l_B_paper"), ".3f"),
            )
        _emit(table)
        return
    table = Table("species", "family", "description")
    for name, path in species.items():
        try:
            spec = load_species(name)
            table.add_row(name, spec.family, getattr(spec, "description", ""))
        except (InputError, ImportError) as exc:
            table.add_row(name, "?", f"invalid: {exc}" if isinstance(exc, InputError) else str(path))
    _emit(table)


@app.command("suites")
def suites_cmd() -> None:
    """List the suites."""
    from rich.table import Table

    from plantbench.suites import load_suite, suites

    table = Table("suite", "cases", "methods", "views", "description")
    for name, _ in suites.items():
        try:
            s = load_suite(name)
        except PlantbenchError as exc:  # e.g. a suite of real scans whose data folder is not on this machine
            table.add_row(name, "-", "-", "-", f"cannot load: {exc}")
            continue
        n_cases = sum(c.count for c in s.cases)
        table.add_row(name, str(n_cases), ", ".join(s.methods), str(s.capture.views), s.description)
    _emit(table)


@app.command("methods")
def methods_cmd(
    name: Annotated[Optional[str], typer.Argument(help="A method: list its options.")] = None,  # noqa: UP045
) -> None:
    """List the registered methods (shipped and plugins); with NAME, that method's options (name, default, unit,
    meaning), which a suite's [method_options.NAME] table or `plantbench reconstruct --option NAME=VALUE` set."""
    from rich.table import Table

    from plantbench.registry import methods

    if name is not None:
        from plantbench.methods.api import method_from_spec
        from plantbench.methods.options import describe_options

        method = method_from_spec(name)
        rows = describe_options(method)
        if not rows:
            typer.echo(f"{name}: takes no options")
            return
        table = Table("option", "default", "unit", "meaning", title=f"{name} options")
        for r in rows:
            table.add_row(r.name, repr(r.default), r.unit, r.meaning)
        _emit(table)
        return
    table = Table("method", "inputs", "module")
    for key, m in methods.items():
        table.add_row(key, m.inputs, type(m).__module__)
    for key, err in methods.load_errors().items():
        table.add_row(key, "-", f"failed to load: {err}")
    _emit(table)


@app.command("metrics")
def metrics_cmd(
    headline: Annotated[bool, typer.Option("--headline", help="Only the report's headline metrics.")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="JSON (name, unit, higher_is_better, description).")]
    = False,
) -> None:
    """List the metrics `plantbench evaluate` writes (unit, direction, definition); --headline: the calibrated
    headline metrics the report leads with and `plantbench gate` checks."""
    import json

    from plantbench.metrics.info import HEADLINE, METRICS

    names = list(HEADLINE) if headline else list(METRICS)
    rows = [METRICS[n] for n in names]
    if as_json:
        typer.echo(json.dumps([{"name": r.name, "unit": r.unit, "higher_is_better": r.higher_is_better,
                                "description": r.description, "headline": r.name in HEADLINE} for r in rows],
                              indent=1))
        return
    arrow = {True: "higher", False: "lower", None: "-"}
    if not sys.stdout.isatty():  # plain columns for grep and scripts
        for r in rows:
            typer.echo(f"{r.name}\t{r.unit or '-'}\t{arrow[r.higher_is_better]}\t{r.description}")
        return
    from rich.table import Table

    table = Table("metric", "unit", "better", "definition", title="headline metrics" if headline else "metrics")
    for r in rows:
        table.add_row(r.name + (" *" if r.name in HEADLINE and not headline else ""), r.unit, arrow[r.higher_is_better],
                      r.description)
    _console().print(table)

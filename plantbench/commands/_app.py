"""The ``plantbench`` Typer application and what every command group shares: the console, the progress bar, plain
tables in a pipe. Only the command modules print or exit."""

from __future__ import annotations

import sys
from typing import Annotated

import typer

app = typer.Typer(
    name="plantbench",
    help="Benchmark suite with synthetic ground truth for 3D plant reconstruction.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)

_state = {"debug": False}


def _console():
    from rich.console import Console

    return Console()


def _progress_bar(console):
    """The progress bar of a long command: description, bar, done/total, elapsed time, drawn on a terminal; into a
    pipe or a file, a plain line at every tenth of the work instead (a log holds no bar characters)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    class _Progress(Progress):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self._logged: dict = {}

        def update(self, task_id, **kwargs):
            super().update(task_id, **kwargs)
            task = self._tasks[task_id]
            if self.disable and task.total:
                tenth = int(10 * task.completed / task.total)
                if tenth > self._logged.get(task_id, 0):
                    self._logged[task_id] = tenth
                    self.console.print(f"{task.description}: {task.completed:.0f}/{task.total:.0f}, "
                                       f"{task.elapsed or 0:.0f} s", markup=False, highlight=False)

        def advance(self, task_id, advance=1):
            self.update(task_id, advance=advance)

        def reset(self, task_id, **kwargs):
            super().reset(task_id, **kwargs)
            self._logged.pop(task_id, None)

    return _Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                     console=console, disable=not console.is_terminal)


def _emit(table) -> None:
    """Print a rich Table: boxed on a terminal; plain tab-separated columns (a header line, then one line per row)
    into a pipe or file, for grep and scripts."""
    if sys.stdout.isatty():
        _console().print(table)
        return
    cols = table.columns
    typer.echo("\t".join(str(c.header) for c in cols))
    for i in range(table.row_count):
        typer.echo("\t".join(str(c._cells[i]) for c in cols))


def _group(name: str, help: str) -> typer.Typer:
    """A group of subcommands, ``plantbench NAME ...``."""
    group = typer.Typer(help=help, no_args_is_help=True)
    app.add_typer(group, name=name)
    return group


@app.callback()
def _root(
    debug: Annotated[bool, typer.Option("--debug", help="Show tracebacks on errors.")] = False,
    version: Annotated[bool, typer.Option("--version", help="Print the version and exit.")] = False,
) -> None:
    _state["debug"] = debug
    if version:
        from plantbench import __version__

        typer.echo(__version__)
        raise typer.Exit(0)

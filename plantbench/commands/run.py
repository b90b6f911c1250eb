"""Commands on a suite run: ``run``, ``report``, ``compare``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from plantbench.commands._app import _console, _progress_bar, app
from plantbench.errors import InputError


@app.command()
def run(
    suite: Annotated[str, typer.Option(help="Suite name (see `plantbench suites`) or path to a suite TOML.")],
    methods: Annotated[Optional[str], typer.Option(help="Comma-separated methods overriding the suite's.")] = None,  # noqa: UP045
    workers: Annotated[int, typer.Option(help="Parallel workers.")] = 1,
    executor: Annotated[str, typer.Option(help="local or dask.")] = "local",
    scheduler: Annotated[Optional[str], typer.Option(help="Dask scheduler address.")] = None,  # noqa: UP045
    out: Annotated[Path, typer.Option(help="Run folder.")] = Path("runs"),
    dataset: Annotated[Optional[Path], typer.Option(  # noqa: UP045
        help="A frozen dataset of the suite (`plantbench dataset pack`): run the methods on its captures.")] = None,
) -> None:
    """Run a suite: cases x methods, cached and resumable; writes the results table."""
    from plantbench.runner import run_suite
    from plantbench.suites import load_suite

    spec = load_suite(suite)
    method_list = [m.strip() for m in methods.split(",")] if methods else None
    frozen = None
    if dataset is not None:  # verified once, before any progress is shown
        from plantbench.dataset import open_dataset

        frozen = open_dataset(dataset, spec)
    console = _console()
    with _progress_bar(console) as bar:
        task = bar.add_task(f"suite {spec.name}", total=None)

        def progress(done: int, total: int, rec: dict) -> None:
            state = "reused" if rec.get("reused") else rec["status"]
            bar.update(task, completed=done, total=total, description=f"suite {spec.name}: {rec['kind']} {state}")
            if rec["status"] != "ok" and not rec.get("upstream"):
                bar.console.print(f"[red]{rec['kind']} {rec['key']} {rec['status']}[/red]: {rec.get('error')}")

        try:
            result = run_suite(spec, out, methods=method_list, workers=workers, executor=executor,
                               scheduler=scheduler, progress=progress, dataset=frozen)
        except KeyboardInterrupt:
            console.print("interrupted: finished jobs are cached; run the same command again to resume")
            raise typer.Exit(130) from None
    st = result.stats
    console.print(
        f"{result.run_dir}: {st['computed']} jobs computed, {st['reused']} reused from the cache, "
        f"{st['failed']} failed ({st['skipped']} skipped after an upstream failure), {result.seconds:.1f} s"
    )
    from plantbench.report.gate import read_run_meta
    from plantbench.report.tables import summary_lines

    oracles = tuple(read_run_meta(result.run_dir).get("oracles") or ())
    for line in summary_lines(result.table, oracles=oracles):
        typer.echo(line)


@app.command()
def report(
    run_dir: Annotated[Path, typer.Argument(metavar="RUN", help="A run folder (holding results.parquet).")],
    fmt: Annotated[str, typer.Option("--format", help="Comma-separated: md, latex, csv, html.")] = "md,latex,csv,html",
    out: Annotated[Optional[Path], typer.Option(help="Output folder (default RUN/report).")] = None,  # noqa: UP045
    calibration: Annotated[Optional[Path], typer.Option(  # noqa: UP045
        help="A `plantbench calibrate` folder for the note on S_T [default: reports/calibration].")] = None,
) -> None:
    """Write tables (mean and 95 % bootstrap CI per method, species, family) and figures for a run."""
    from plantbench.report.report import write_report

    files = write_report(run_dir, tuple(f.strip() for f in fmt.split(",")), out, calibration=calibration)
    for f in files:
        typer.echo(str(f))


@app.command()
def compare(
    run_a: Annotated[Path, typer.Argument(metavar="RUN_A", help="A run folder (e.g. the multiview suite's).")],
    run_b: Annotated[Path, typer.Argument(metavar="RUN_B", help="A run of the same cases (e.g. multiview_oracle).")],
    label_a: Annotated[str, typer.Option(help="What run A is, for the table.")] = "a",
    label_b: Annotated[str, typer.Option(help="What run B is, for the table.")] = "b",
    out: Annotated[Optional[Path], typer.Option(  # noqa: UP045
        help="Also write the table here: .csv, or .md for a markdown table.")] = None,
    metric: Annotated[Optional[list[str]], typer.Option(  # noqa: UP045
        help="A metric to compare (repeat the option for several; `plantbench metrics` lists them) "
             "[default: the report's key metrics].")] = None,
) -> None:
    """Each method of two runs of the same cases, paired over the cases: means, B - A with its 95 % bootstrap
    interval, and whether B is better, worse or within noise (e.g. the mvs cloud against the oracle cloud: how much
    of a method's error is the cloud's)."""
    from plantbench.io.atomic import atomic_write
    from plantbench.registry import did_you_mean
    from plantbench.report.gate import read_results
    from plantbench.report.tables import KEY_METRICS, compare_runs

    if label_a == label_b:
        raise InputError(f"--label-a and --label-b must differ (both {label_a!r})")
    if metric:
        from plantbench.metrics.info import METRICS

        for m in metric:
            if m not in METRICS and m != "runtime_s":
                raise InputError("--metric: " + did_you_mean("metric", m, [*METRICS, "runtime_s"]))
    table = compare_runs(read_results(run_a), read_results(run_b), label_a=label_a, label_b=label_b,
                         metrics=tuple(metric) if metric else KEY_METRICS)
    if table.empty:
        raise InputError(f"no method scored in both runs ({run_a}, {run_b})")
    md = _compare_markdown(table, label_a, label_b)
    if out is not None:
        with atomic_write(out, "w") as fh:
            if out.suffix == ".md":
                fh.write(md)
            else:
                table.to_csv(fh, index=False)
    typer.echo(md, nl=False)  # markdown reads the same on a terminal and pastes into a report


def _compare_markdown(table, label_a: str, label_b: str) -> str:
    from plantbench.report.tables import format_value, metric_info

    lines = [f"| method | metric | n | {label_a} | {label_b} | {label_b} - {label_a} [95 % CI] | verdict |",
             "|---|---|---|---|---|---|---|"]
    for r in table.itertuples():
        info = metric_info(r.metric)
        arrow = "" if info is None or info.higher_is_better is None else " ↑" if info.higher_is_better else " ↓"
        lines.append(f"| {r.method} | {r.metric}{arrow} | {r.n} | {format_value(r.mean_a)} | {format_value(r.mean_b)} "
                     f"| {r.diff:+.3f} [{r.lo:+.3f}, {r.hi:+.3f}] | {r.verdict} |")
    return "\n".join(lines) + "\n"

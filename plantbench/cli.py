"""The ``plantbench`` command: a thin layer over library functions.

Only this module prints or exits. A user mistake (InputError: unknown name, malformed file, invalid value) prints
one line and exits 2; a method or stage that fails exits 1 with a one-line message; ``--debug`` shows tracebacks.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from plantbench.errors import InputError, NotAvailableError, PlantbenchError

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


# ------------------------------------------------------------------------------------------------------- stages


@app.command()
def generate(
    species: Annotated[str, typer.Option(help="Species name (see `plantbench species`).")],
    out: Annotated[Path, typer.Option(help="Case folder; plant/ is written inside it.")],
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    scale: Annotated[float, typer.Option(help="Growth budget factor in (0, 1]; < 1 grows smaller plants.")] = 1.0,
) -> None:
    """Grow a plant and write its ground truth (plant/)."""
    from plantbench.generate import generate_case

    meta = generate_case(species, seed, out, scale=scale)
    c = meta.counts
    typer.echo(
        f"{out / 'plant'}: {meta.species} seed {meta.seed}, height {meta.height:.2f} m, {c.branches} branches, "
        f"{c.leaves} leaves, {c.nodes} nodes"
    )


def _settings_parameters(model) -> list:
    """One keyword-only ``--NAME`` option per field of the pydantic ``model``: its type, default and description as
    the model has them (a bool as ``--NAME/--no-NAME``, a pair as two values), so the command's flags are the
    model's fields and nothing else."""
    import inspect

    return [inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=f.default,
                              annotation=Annotated[f.annotation, typer.Option(help=(f.description or name) + ".")])
            for name, f in model.model_fields.items()]


def capture(case: Path, seed: int, **settings) -> None:
    """Render multi-view images with exact depth/instance maps and cameras, and simulate a laser scan. Every
    capture setting is a flag (plantbench.capture.settings.CaptureOptions; a suite's [capture] table takes the same
    names)."""
    import json

    from plantbench.capture import as_options, capture_case

    options = as_options(settings)
    folder = capture_case(case, options, seed=seed)
    scanned = ""
    if options.scan:
        doc = json.loads((Path(case) / "scan" / "stations.json").read_text())
        scanned = (f"; scan from {options.stations} station(s), {doc['points']} points at a median spacing of "
                   f"{100 * doc['median_spacing']:.2f} cm")
    leaves = json.loads((folder / "capture.json").read_text()).get("leaf_pixels") or {}
    if leaves.get("median_px") is not None:
        scanned += (f"; leaves cover {leaves['median_px']:.0f} px per view where visible (median), "
                    f"{leaves['resolved_2_views']} of {leaves['leaves']} cover >= {leaves['resolved_px']} px "
                    "in >= 2 views")
    typer.echo(f"{folder}: {options.views} views at {options.width}x{options.height}, {options.spp} spp{scanned}")


def _register_capture() -> None:
    import inspect

    from plantbench.capture.settings import CaptureOptions

    capture.__signature__ = inspect.Signature([
        inspect.Parameter("case", inspect.Parameter.POSITIONAL_OR_KEYWORD,
                          annotation=Annotated[Path, typer.Argument(help="Case folder holding plant/.")]),
        inspect.Parameter("seed", inspect.Parameter.KEYWORD_ONLY, default=0,
                          annotation=Annotated[int, typer.Option(help="Random seed of the capture (textures, render "
                                                                      "and scan noise).")]),
        *_settings_parameters(CaptureOptions)])
    app.command()(capture)


_register_capture()


@app.command()
def reconstruct(
    case: Annotated[Path, typer.Argument(help="Case folder (a capture).")],
    method: Annotated[str, typer.Option(help="Registered method name, or cmd:\"tool {capture} {out}\".")],
    out: Annotated[Path, typer.Option(help="Output folder for the reconstruction.")],
    seed: Annotated[int, typer.Option(help="Random seed passed to the method.")] = 0,
    species: Annotated[Optional[str], typer.Option(help="Species hint passed to the method.")] = None,  # noqa: UP045
    points: Annotated[Optional[Path], typer.Option(  # noqa: UP045
        help="For a points method: the folder holding points.ply (an mvs output) [default: the case's scan].")] = None,
) -> None:
    """Run one method on one case, on the same input folder the runner prepares (only what a real capture gives,
    plus the species hint)."""
    from plantbench.methods.api import method_from_spec
    from plantbench.methods.inputs import run_isolated

    m = method_from_spec(method)
    if not case.is_dir():
        raise InputError("case folder not found", path=case)
    run_isolated(m, case, out, seed=seed, species=species, points_dir=points)
    typer.echo(f"{m.name}: wrote {out}")


@app.command()
def evaluate(
    case: Annotated[Path, typer.Argument(help="Case folder with ground truth.")],
    recon: Annotated[Path, typer.Argument(help="A method's output folder.")],
    json_out: Annotated[Optional[Path], typer.Option("--json", help="Write all metrics as JSON here.")] = None,  # noqa: UP045
) -> None:
    """Score a reconstruction against a case's ground truth: every metric, components included."""
    from plantbench.io.atomic import write_json
    from plantbench.metrics.evaluate import evaluate_detailed, format_summary

    values, reasons = evaluate_detailed(case, recon)
    _emit(format_summary(values, reasons))
    if json_out is not None:
        write_json(json_out, values)
        typer.echo(f"wrote {json_out}")


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


@app.command()
def gate(
    run_dir: Annotated[Path, typer.Argument(metavar="RUN", help="A run folder (holding results.parquet).")],
    baseline: Annotated[Path, typer.Option(help="Baseline JSON (headline metric values per method and case).")] = Path(
        "reports/baseline.json"),
    tolerances: Annotated[Optional[Path], typer.Option(  # noqa: UP045
        help="Tolerances JSON from the variability study [default: tolerances.json beside the baseline].")] = None,
    write: Annotated[bool, typer.Option("--write", help="Write the baseline from this run instead of comparing.")] = False,
) -> None:
    """Compare a run's headline metrics, per method and case, with a baseline; exit 1 naming every metric that moved
    in its bad direction beyond its tolerance (from the variability study: `plantbench variability`)."""
    from rich.table import Table

    from plantbench.report.gate import (
        compare,
        load_baseline,
        load_tolerances,
        make_baseline,
        read_results,
        read_run_meta,
        regression_lines,
        tolerances_path,
        write_baseline,
    )

    table = read_results(run_dir)
    if write:
        meta = read_run_meta(run_dir)
        b = make_baseline(table, meta.get("suite", run_dir.name), llvm_target=meta.get("llvm_target"),
                          git_sha=meta.get("git_sha"))
        write_baseline(baseline, b)
        typer.echo(f"{baseline}: {len(b.entries)} headline values (method x case x metric) from {run_dir}")
        return
    tol_file = tolerances or tolerances_path(baseline)
    tol = load_tolerances(tol_file) if tolerances is not None or tol_file.exists() else None
    result = compare(table, load_baseline(baseline), tol)
    bad = result[result["regressed"]]
    console = _console()
    floor_only = int((result["source"] == "floor").sum())
    note = f" ({floor_only} with the floor tolerance only: not in {tol_file})" if floor_only else ""
    say = console.print if console.is_terminal else typer.echo  # a log gets plain lines, never wrapped or cut
    if bad.empty:
        say(f"gate passed: {len(result)} headline metrics within tolerance of {baseline}{note}")
        return
    if console.is_terminal:
        out = Table("method", "case", "metric", "baseline", "now", "change", "tolerance", "better", title="regressions")
        for r in bad.itertuples():
            missing = r.value != r.value
            out.add_row(r.method, r.case, r.metric, f"{r.baseline:.4g}", "missing" if missing else f"{r.value:.4g}",
                        "" if missing else f"{r.delta:+.3g}",
                        f"{r.tolerance:.3g}" + (" (floor)" if r.source == "floor" else ""),
                        "higher" if r.higher_is_better else "lower")
        console.print(out)
    else:
        for line in regression_lines(result):
            typer.echo(line)
    say(f"gate failed: {len(bad)} of {len(result)} headline metrics regressed{note}")
    raise typer.Exit(1)


@app.command()
def calibrate(
    suite: Annotated[str, typer.Option(help="Suite name or path to a suite TOML.")] = "multiview",
    workers: Annotated[int, typer.Option(help="Parallel workers.")] = 1,
    out: Annotated[Path, typer.Option(help="Run folder (the cache is shared with `plantbench run`).")] = Path("runs"),
    reports: Annotated[Path, typer.Option(help="Where README.md, ladder.csv.gz, verdicts.csv and the figure go.")] = Path(
        "reports/calibration"),
    seed: Annotated[Optional[int], typer.Option(  # noqa: UP045
        help="Replace every case's seed (plants that are not in the suite).")] = None,
    species: Annotated[Optional[str], typer.Option(  # noqa: UP045
        help="Comma-separated species: only these cases of the suite.")] = None,
    from_run: Annotated[Optional[Path], typer.Option(  # noqa: UP045
        help="Re-make the verdicts and report from an earlier calibration run folder instead of running.")] = None,
) -> None:
    """Score a ladder of controlled reconstructions of each plant (ground truth pruned, jittered, scaled, leaves
    moved; the no-data prior; another species) with every metric, and say which metrics order them by fidelity."""
    import time

    from plantbench.metrics.info import HEADLINE_FIDELITY, HEADLINE_STRUCTURE
    from plantbench.report.calibration import run_calibration, write_calibration
    from plantbench.report.gate import read_results, read_run_meta
    from plantbench.suites import load_suite

    console = _console()
    t0 = time.perf_counter()
    if from_run is not None:
        run_dir, table = from_run, read_results(from_run)
        how = f"`plantbench calibrate --from-run {from_run}`"
    else:
        spec = load_suite(suite)
        chosen = [s.strip() for s in species.split(",")] if species else None
        with _progress_bar(console) as bar:
            task = bar.add_task("calibration", total=None)

            def progress(done: int, total: int, rec: dict) -> None:
                bar.update(task, completed=done, total=total,
                           description=f"calibration: {rec['kind']} {rec['status']}")

            result = run_calibration(spec, out, workers=workers, progress=progress, seed=seed, species=chosen)
        run_dir, table = result.run_dir, result.table
        how = (f"`plantbench calibrate --suite {spec.name}" + (f" --seed {seed}" if seed is not None else "")
               + (f" --species {species}" if species else "") + "`")
    meta = read_run_meta(run_dir)
    header = (f"Made by {how} (run {meta.get('suite', run_dir.name)}, code {meta.get('git_sha')}, "
              f"{table['case'].nunique()} plants, run time {meta.get('seconds', float('nan')):.0f} s).")
    verdict, _ = write_calibration(table, reports, header=header)
    good = verdict[verdict["verdict"] == "discriminates"]
    console.print(f"{reports}/README.md: {len(good)} of {len(verdict)} metrics discriminate "
                  f"({table['case'].nunique()} plants, {time.perf_counter() - t0:.0f} s)")
    seeing = set(verdict.loc[verdict["structure"] == "discriminates", "metric"])
    failed = [m for m in HEADLINE_FIDELITY if m not in set(good["metric"])]
    failed += [f"{m} (structure)" for m in HEADLINE_STRUCTURE if m not in seeing]
    if failed:
        console.print(f"[red]headline metrics that do not discriminate here: {', '.join(failed)}[/red]")


@app.command()
def variability(
    suite: Annotated[str, typer.Option(help="Suite name or path to a suite TOML.")] = "quick",
    out: Annotated[Path, typer.Option(help="Folder of the study's runs (one run folder and cache per run).")] = Path(
        "runs/variability"),
    reports: Annotated[Path, typer.Option(help="Where baseline.json, tolerances.json and variability/ are written.")]
    = Path("reports"),
    only: Annotated[Optional[str], typer.Option(  # noqa: UP045
        help="Comma-separated perturbations to run besides the reference (default: all this CPU can run).")] = None,
    another_cpu: Annotated[bool, typer.Option(
        "--another-cpu", help="Run only the reference configuration here and add it, named after this CPU, to the "
                              "study in REPORTS/variability/study.csv; the tolerances are re-made from the grown study "
                              "and the baseline (the first machine's reference run) stays.")] = False,
) -> None:
    """Run a suite under perturbations that carry no meaning (Dr.Jit target and vector width, +-1 grey level of
    image noise, thread count), then write the gate's baseline (the reference run) and its tolerances.

    With --another-cpu, a study made on one machine grows by the reference configuration run on this one: the gate
    then allows what another CPU moves."""
    import time
    from dataclasses import replace

    from plantbench.backend import host_cpu_name
    from plantbench.io.atomic import atomic_write
    from plantbench.report.gate import make_baseline, read_run_meta, write_baseline, write_tolerances
    from plantbench.report.variability import (
        PERTURBATIONS,
        available_perturbations,
        extend_study,
        run_study,
        study_markdown,
        study_perturbations,
        study_table,
        tolerances_from_study,
    )
    from plantbench.report.variability import another_cpu as other_cpu
    from plantbench.suites import load_suite

    spec = load_suite(suite)
    console = _console()
    folder = reports / "variability"
    previous = None
    if another_cpu:
        if only:
            raise InputError("--another-cpu runs the reference configuration only: leave out --only")
        previous = _read_study(folder / "study.csv")
        here = other_cpu(host_cpu_name())
        chosen = [replace(available_perturbations(["reference"])[0], name=here.name, description=here.description)]
    else:
        chosen = available_perturbations([n.strip() for n in only.split(",")] if only else None)
    skipped = [] if another_cpu else [p for p in PERTURBATIONS if p not in chosen and (not only or p.name in only)]
    for p in skipped:
        console.print(f"skipped {p.name}: this CPU lacks {p.requires}")

    t0 = time.perf_counter()
    with _progress_bar(console) as bar:
        runs = bar.add_task("study", total=len(chosen))
        jobs = bar.add_task("jobs", total=None)

        def on_run(p) -> None:
            bar.update(runs, completed=chosen.index(p), description=f"study: run {p.name}")
            bar.reset(jobs)
            bar.console.print(f"{p.name}: {p.description}")

        def progress(done: int, total: int, rec: dict) -> None:
            bar.update(jobs, completed=done, total=total, description=f"jobs: {rec['kind']} {rec['status']}")

        tables = run_study(spec, out, perturbations=chosen, on_run=on_run, progress=progress)
        bar.update(runs, completed=len(chosen))
    study = study_table(tables) if previous is None else extend_study(previous, tables)
    tol = tolerances_from_study(study, spec.name)
    folder.mkdir(parents=True, exist_ok=True)
    with atomic_write(folder / "study.csv", "w") as fh:
        study.to_csv(fh, index=False)
    meta = read_run_meta(out / chosen[0].name / spec.name)
    made = (f"Made by `plantbench variability --suite {spec.name}` on {host_cpu_name()} "
            f"(code {meta.get('git_sha')}, {time.perf_counter() - t0:.0f} s for {len(chosen)} runs).")
    if previous is not None:  # the first machine's header stays; this run is added below it
        lines = (folder / "README.md").read_text().splitlines() if (folder / "README.md").is_file() else []
        end = next((i for i, line in enumerate(lines) if line.startswith("| run |")), len(lines))
        old = "\n".join(line for line in lines[1:end] if not line.startswith(f"Run {chosen[0].name} ")).strip()
        made = f"{old}\n\nRun {chosen[0].name} added by `plantbench variability --suite {spec.name} " \
               f"--another-cpu` on {host_cpu_name()} (code {meta.get('git_sha')}, " \
               f"{time.perf_counter() - t0:.0f} s)."
    else:
        made += (" study.csv holds every run's headline values; ../tolerances.json the tolerances; ../baseline.json "
                 "the reference run's values.")
    with atomic_write(folder / "README.md", "w") as fh:
        fh.write(study_markdown(study, tol, study_perturbations(study), header=made))
    write_tolerances(reports / "tolerances.json", tol)
    if previous is None:
        write_baseline(reports / "baseline.json", make_baseline(tables["reference"], spec.name,
                                                                llvm_target=meta.get("llvm_target"),
                                                                git_sha=meta.get("git_sha")))
    console.print(f"{folder}/README.md, {reports}/tolerances.json ({len(tol.entries)} cells)"
                  + (f", {reports}/baseline.json" if previous is None else " (baseline kept)")
                  + f": {len(chosen)} runs in {time.perf_counter() - t0:.0f} s")


def _read_study(path: Path):
    """A committed study table (study.csv), checked for its columns and a reference run."""
    import pandas as pd

    from plantbench.report.variability import STUDY_COLUMNS

    if not path.is_file():
        raise InputError("no study to add to: run `plantbench variability` on the first machine", path=path)
    try:
        study = pd.read_csv(path)
    except (OSError, ValueError) as exc:
        raise InputError(f"unreadable study table: {exc}", path=path) from None
    if list(study.columns) != STUDY_COLUMNS or "reference" not in set(study["perturbation"]):
        raise InputError(f"not a study table (columns {STUDY_COLUMNS} and a 'reference' run)", path=path)
    return study


dataset_app = _group("dataset", "Frozen datasets: a suite's ground truth and captures with a sha256 manifest.")


@dataset_app.command("pack")
def dataset_pack(
    suite: Annotated[str, typer.Option(help="Suite name (see `plantbench suites`) or path to a suite TOML.")],
    out: Annotated[Path, typer.Option(help="Dataset folder to write (must not exist).")],
    cache: Annotated[Path, typer.Option(help="Job cache to generate and capture through.")] = Path("runs/cache"),
    workers: Annotated[int, typer.Option(help="Parallel workers.")] = 1,
    force: Annotated[bool, typer.Option("--force", help="Replace OUT if it exists.")] = False,
) -> None:
    """Generate and capture every case of a suite and write them with a manifest (sha256 of every file, versions,
    code hashes, licence) and a datasheet."""
    from plantbench.dataset import manifest_sha256, pack_suite
    from plantbench.suites import load_suite

    spec = load_suite(suite)
    manifest = pack_suite(spec, out, cache=cache, workers=workers, force=force)
    typer.echo(f"{out}: {len(manifest.cases)} cases, {len(manifest.files)} files, {manifest.bytes / 2**20:.1f} MiB; "
               f"manifest sha256 {manifest_sha256(out)}")


@dataset_app.command("verify")
def dataset_verify(
    folder: Annotated[Path, typer.Argument(metavar="DIR", help="A dataset folder.")],
) -> None:
    """Check every file of a dataset against its manifest; exit 2 naming the first missing, altered or unlisted one."""
    from plantbench.dataset import manifest_sha256, verify_dataset

    manifest = verify_dataset(folder)
    typer.echo(f"{folder}: {len(manifest.files)} files verified (suite {manifest.suite}, {len(manifest.cases)} cases); "
               f"manifest sha256 {manifest_sha256(folder)}")


import_app = _group("import",
                    "Real captures in: a scan file, or photos with a COLMAP model, become a case (no plant/).")


@import_app.command("scan")
def import_scan_cmd(
    file: Annotated[Path, typer.Argument(metavar="FILE", help="Scan file: .xyz .txt .csv .ply .las .laz .pcd.")],
    out: Annotated[Path, typer.Option(help="Case folder to create (absent or empty).")],
    units: Annotated[str, typer.Option(help="Units of the file's coordinates: m, cm or mm.")] = "m",
    up: Annotated[str, typer.Option(help="The file's axis that points up: z, -z, y, -y, x, -x.")] = "z",
    max_height: Annotated[float, typer.Option(help="Refuse a cloud taller than this (metres, after --units).")]
    = 100.0,
) -> None:
    """Import a laser scan as CASE/scan/ (metres, Z up, root at the origin); the frame goes to CASE/case.json."""
    from plantbench.capture.importers import import_scan

    res = import_scan(file, out, units=units, up=up, max_height=max_height)
    r = res.record
    typer.echo(f"{out}: {r.source.points} points from {file.name}, {r.height:.2f} m tall; " + "; ".join(res.notes))


@import_app.command("views")
def import_views_cmd(
    images: Annotated[Path, typer.Option(help="Folder holding the images under the names the COLMAP model uses.")],
    colmap: Annotated[Path, typer.Option(help="COLMAP model folder (cameras, images, points3D; .txt or .bin).")],
    out: Annotated[Path, typer.Option(help="Case folder to create (absent or empty).")],
    scale: Annotated[Optional[float], typer.Option(  # noqa: UP045
        help="Metres per model unit [default: 1, recorded as assumed].")] = None,
    up: Annotated[str, typer.Option(help="auto (the cameras' mean up vector) or the model's up axis: z, -z, y, ...")]
    = "auto",
) -> None:
    """Import photos with a COLMAP model as CASE/views/ (OpenCV cameras in metres, Z up, root at the origin)."""
    from plantbench.capture.importers import import_views

    res = import_views(images, colmap, out, scale=scale, up=up)
    for note in res.notes[:-1]:
        typer.echo(f"note: {note}")
    typer.echo(f"{out}: {res.notes[-1]}")


qsm_app = _group("qsm", "QSM cylinder tables (TreeQSM / rTwig columns) to and from skeletons.")

_CaseOption = Annotated[Optional[Path], typer.Option(  # noqa: UP045
    help="An imported case: the QSM is in the frame of the file imported into it (units, axes, georeference).")]


def _case_frame(skeleton, case: Path | None, to: str):
    """``skeleton`` moved into the imported ``case``'s source frame (``to="source"``) or from it into the local one
    (``to="local"``); unchanged without a case."""
    if case is None:
        return skeleton
    from plantbench.capture.importers import read_case_json, skeleton_to_frame

    return skeleton_to_frame(skeleton, read_case_json(case).frame, to=to)


@qsm_app.command("export")
def qsm_export(
    recon: Annotated[Path, typer.Argument(metavar="RECON_DIR", help="A method's output folder (skeleton.ply).")],
    out: Annotated[Path, typer.Option(help="CSV file to write.")],
    case: _CaseOption = None,
) -> None:
    """Write a reconstruction's skeleton as a cylinder table (one cylinder per edge)."""
    from plantbench.io.ply import read_skeleton
    from plantbench.io.qsm import write_qsm_csv

    skeleton = _case_frame(read_skeleton(recon / "skeleton.ply"), case, to="source")
    df = write_qsm_csv(out, skeleton)
    typer.echo(f"{out}: {len(df)} cylinders, {df['branch'].nunique()} branches")


@qsm_app.command("import")
def qsm_import(
    file: Annotated[Path, typer.Argument(metavar="FILE.csv", help="Cylinder table CSV (start_x ... branch_order).")],
    out: Annotated[Path, typer.Option(help="Output folder: skeleton.ply is written there, for `plantbench evaluate`.")],
    case: _CaseOption = None,
) -> None:
    """Read a cylinder table (TreeQSM, rTwig) as a reconstruction's skeleton.ply."""
    from plantbench.io.plantio import write_reconstruction
    from plantbench.io.qsm import read_qsm_csv

    skeleton = _case_frame(read_qsm_csv(file), case, to="local")
    write_reconstruction(out, skeleton)
    typer.echo(f"{out / 'skeleton.ply'}: {len(skeleton)} nodes, {len(skeleton.roots)} root(s)")


# ------------------------------------------------------------------------------------------------------ listings


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
def methods_cmd() -> None:
    """List the registered methods (shipped and plugins)."""
    from rich.table import Table

    from plantbench.registry import methods

    table = Table("method", "inputs", "module")
    for name, m in methods.items():
        table.add_row(name, m.inputs, type(m).__module__)
    for name, err in methods.load_errors().items():
        table.add_row(name, "-", f"failed to load: {err}")
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


# -------------------------------------------------------------------------------------------------------- entry


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

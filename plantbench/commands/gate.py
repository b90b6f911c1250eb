"""The gate and what makes its numbers: ``gate``, ``calibrate``, ``variability``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from plantbench.commands._app import _console, _progress_bar, app
from plantbench.errors import InputError


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
    image noise, thread count, the methods' input cloud shuffled or moved by 1e-6 m, OpenBLAS's and numpy's own
    kernels), then write the gate's baseline (the reference run) and its tolerances.

    With --another-cpu, a study made on one machine grows by the reference configuration run on this one: the gate
    then allows what another CPU moves."""
    import time
    from dataclasses import replace

    from plantbench.backend import host_cpu_name
    from plantbench.report.gate import read_run_meta
    from plantbench.report.variability import PERTURBATIONS, available_perturbations, read_study, run_study, write_study
    from plantbench.report.variability import another_cpu as other_cpu
    from plantbench.suites import load_suite

    spec = load_suite(suite)
    console = _console()
    folder = reports / "variability"
    previous = None
    if another_cpu:
        if only:
            raise InputError("--another-cpu runs the reference configuration only: leave out --only")
        previous = read_study(folder / "study.csv")
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
    written = write_study(reports, spec.name, tables, chosen, previous=previous, seconds=time.perf_counter() - t0,
                          meta=read_run_meta(out / chosen[0].name / spec.name))
    console.print(", ".join(str(p) for p in written) + f": {len(chosen)} runs in {time.perf_counter() - t0:.0f} s"
                  + ("" if previous is None else " (baseline kept)"))



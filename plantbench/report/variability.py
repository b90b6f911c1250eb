"""The variability study: a suite run again under perturbations that carry no meaning, and the gate's tolerances.

A perturbation changes nothing a reconstruction should depend on: Dr.Jit's code generation (vector width, the
instruction set of another CPU), +-1 grey level of noise on the images, the number of threads of each job, the order
of a points method's input cloud and a 1e-6 m move of its coordinates, OpenBLAS's and numpy's kernels where the
pins (:func:`plantbench.backend.pin_dispatch`) are overridden. How far
each headline metric of each (method, case) cell moves under them is the noise floor of that number; the gate's
tolerance is max(3 x sd, largest change seen, floor) (:func:`tolerances_from_study`), so that the gate passes every
run of the study and flags what moves beyond its noise.

Each perturbation runs in its own run folder with its own job cache (the thread count is not part of a job's key).
"""

from __future__ import annotations

import contextlib
import math
import os
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from plantbench.methods.inputs import PERTURB_ENV
from plantbench.report.gate import FLOORS, GATED, ToleranceEntry, Tolerances, cell_values

__all__ = ["Perturbation", "PERTURBATIONS", "available_perturbations", "study_table", "tolerances_from_study",
           "run_study", "STUDY_COLUMNS", "another_cpu", "extend_study", "study_perturbations", "read_study",
           "write_study", "input_noise_against_grey", "INPUT_RUNS", "GREY_RUNS"]

INPUT_RUNS = ("order", "jitter")
"""The runs that change a points method's input and nothing else: a method must move no more under them than under
the grey-level noise (:func:`input_noise_against_grey`)."""
GREY_RUNS = ("noise1-a", "noise1-b", "noise1-c")

STUDY_COLUMNS = ["perturbation", "method", "case", "metric", "value"]

_AVX2 = "haswell:+avx,+avx2,+fma,+f16c,+bmi,+bmi2,+lzcnt,+popcnt,+sse4.2,+sse4.1,+ssse3,+sse3"
_AVX512 = ("skylake-avx512:+avx512f,+avx512dq,+avx512vl,+avx512bw,+avx512cd,+avx,+avx2,+fma,+f16c,+bmi,+bmi2,+lzcnt,"
           "+popcnt,+sse4.2,+sse4.1,+ssse3,+sse3")


@dataclass(frozen=True)
class Perturbation:
    """One run of the study.

    name : folder name and label
    description : what it changes, for the study's report
    env : environment variables of the run (and so of its job processes)
    capture : overrides of the suite's ``[capture]`` table
    workers : parallel jobs (with 2 cores: 2 workers give each job 1 thread, 1 worker gives it 2)
    requires : CPU features (LLVM names) the perturbation needs; skipped on a CPU without them
    """

    name: str
    description: str
    env: dict[str, str] = field(default_factory=dict)
    capture: dict[str, int] = field(default_factory=dict)
    workers: int = 2
    requires: str = ""


PERTURBATIONS = (
    Perturbation("reference", "the defaults: Dr.Jit pinned to AVX2 at width 8, 2 workers (1 thread per job)"),
    Perturbation("avx2-width4", "Dr.Jit kernels at vector width 4 (AVX2)",
                 env={"PLANTBENCH_LLVM_TARGET": f"{_AVX2}:4"}),
    Perturbation("avx512-width16", "Dr.Jit kernels for AVX-512 at width 16 (what an AVX-512 host picks unpinned)",
                 env={"PLANTBENCH_LLVM_TARGET": f"{_AVX512}:16"}, requires="+avx512f,+avx512dq,+avx512vl,+avx512bw"),
    Perturbation("noise1-a", "+-1 grey level of uniform noise on every image channel (draw 1)",
                 capture={"image_noise": 1, "image_noise_seed": 1}),
    Perturbation("noise1-b", "+-1 grey level of uniform noise on every image channel (draw 2)",
                 capture={"image_noise": 1, "image_noise_seed": 2}),
    Perturbation("noise1-c", "+-1 grey level of uniform noise on every image channel (draw 3)",
                 capture={"image_noise": 1, "image_noise_seed": 3}),
    Perturbation("threads2", "1 worker: each job's thread pools (Dr.Jit, BLAS, cKDTree, Open3D) use both cores",
                 workers=1),
    Perturbation("order", "every points method's input cloud in another order (a seeded permutation of its rows)",
                 env={PERTURB_ENV: "order:1"}),
    Perturbation("jitter", "every coordinate of every points method's input cloud moved by a uniform draw in "
                 "[-1e-6, 1e-6] m", env={PERTURB_ENV: "jitter:1e-6:1"}),
    Perturbation("blas-skylakex", "OpenBLAS's AVX-512 kernels (OPENBLAS_CORETYPE=SkylakeX: what an Intel Xeon or an "
                 "AMD Zen 4 picks when the pin is overridden)",
                 env={"PLANTBENCH_DISPATCH": "host", "OPENBLAS_CORETYPE": "SkylakeX"},
                 requires="+avx512f,+avx512dq,+avx512vl,+avx512bw"),
    Perturbation("numpy-avx512", "numpy's and OpenCV's AVX-512 loops (NPY_DISABLE_CPU_FEATURES and "
                 "OPENCV_CPU_DISABLE empty: what an AVX-512 CPU runs when the pin is overridden)",
                 env={"PLANTBENCH_DISPATCH": "host", "NPY_DISABLE_CPU_FEATURES": "", "OPENCV_CPU_DISABLE": ""},
                 requires="+avx512f,+avx512dq,+avx512vl,+avx512bw"),
)
"""The study's runs, the reference first."""


def available_perturbations(names: list[str] | None = None) -> list[Perturbation]:
    """The perturbations this CPU can run (named ones only, when ``names``); the reference always first."""
    from plantbench.backend import host_has
    from plantbench.errors import InputError

    known = {p.name: p for p in PERTURBATIONS}
    if names:
        unknown = sorted(set(names) - set(known))
        if unknown:
            raise InputError(f"unknown perturbation(s) {unknown}; known: {sorted(known)}")
    chosen = [p for p in PERTURBATIONS if names is None or p.name in names or p.name == "reference"]
    return [p for p in chosen if not p.requires or host_has(p.requires)]


_CPU_PREFIX = "cpu-"


def another_cpu(cpu: str) -> Perturbation:
    """The reference configuration run on another machine, named after its CPU model (``cpu``, e.g. 'AMD EPYC'):
    what the pinned Dr.Jit target leaves to the CPU moves the numbers this far (Embree's own choice of kernels, the
    vendor-specific approximate reciprocals of fast-math kernels: docs/tuning/determinism.md), so the gate must allow
    it."""
    slug = re.sub(r"[^a-z0-9]+", "-", cpu.lower()).strip("-") or "unknown"
    return Perturbation(_CPU_PREFIX + slug, f"the reference configuration on another CPU ({cpu})")


def extend_study(previous, tables: dict[str, object]):
    """``previous`` (a study table, e.g. the committed study.csv) with the runs of ``tables`` added; a run of the same
    name replaces the old one. The previous reference stays the reference."""
    import pandas as pd

    new = study_table(tables)
    kept = previous[~previous["perturbation"].isin(set(new["perturbation"]))]
    return pd.concat([kept, new], ignore_index=True)[STUDY_COLUMNS]


def study_perturbations(study) -> list[Perturbation]:
    """The runs of a study table as :class:`Perturbation` records, in the order of :data:`PERTURBATIONS`, other
    CPUs' runs last (their descriptions name the CPU as far as the run's name does)."""
    names = list(dict.fromkeys(study["perturbation"]))
    known = [p for p in PERTURBATIONS if p.name in names]
    others = [Perturbation(n, f"the reference configuration on another CPU ({n[len(_CPU_PREFIX):]})")
              for n in names if n not in {p.name for p in known}]
    return known + others


@contextlib.contextmanager
def _environment(env: dict[str, str]) -> Iterator[None]:
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def study_table(tables: dict[str, object]):
    """Long table (perturbation, method, case, metric, value) of the headline metrics of each run's results."""
    import pandas as pd

    rows = [{"perturbation": name, "method": m, "case": c, "metric": k, "value": v}
            for name, table in tables.items() for (m, c, k), v in sorted(cell_values(table).items())]
    return pd.DataFrame(rows, columns=STUDY_COLUMNS)


def tolerances_from_study(study, suite: str, *, reference: str = "reference",
                          floors: dict[str, float] | None = None) -> Tolerances:
    """Per (method, case, metric) of the reference run: tolerance = max(3 x sd, max |change|, floor).

    sd is the sample standard deviation (ddof 1) of the cell's finite values over all runs, the reference included;
    max |change| the largest distance of a run's value from the reference's. A cell whose value is missing in the
    reference run gets no entry (the gate does not gate it); one missing in another run is ``may_fail`` (it failed
    under a meaningless perturbation: the gate does not count its failing as a regression, only its values)."""
    floors = dict(FLOORS if floors is None else floors)
    perturbations = [reference] + sorted(set(study["perturbation"]) - {reference})
    entries = []
    for (method, case, metric), grp in study.groupby(["method", "case", "metric"], sort=True):
        ref = grp.loc[grp["perturbation"] == reference, "value"]
        if ref.empty or not math.isfinite(float(ref.iloc[0])):
            continue
        ref_value = float(ref.iloc[0])
        values = grp["value"].to_numpy(float)
        may_fail = bool(len(values) and not np.isfinite(values).all())
        values = values[np.isfinite(values)]
        sd = float(np.std(values, ddof=1)) if values.size > 1 else 0.0
        max_change = float(np.max(np.abs(values - ref_value)))
        floor = floors.get(metric, 0.0)
        terms = {"spread": 3.0 * sd, "max_change": max_change, "floor": floor}
        bound = max(terms, key=terms.get)
        entries.append(ToleranceEntry(method=method, case=case, metric=metric, tolerance=terms[bound], sd=sd,
                                      max_change=max_change, runs=int(values.size), bound=bound,
                                      may_fail=may_fail))
    return Tolerances(suite=suite, perturbations=perturbations, floors={m: floors[m] for m in GATED if m in floors},
                      entries=entries)


def run_study(suite, out: Path, *, perturbations: list[Perturbation] | None = None,
              on_run: Callable[[Perturbation], None] | None = None,
              progress: Callable[[int, int, dict], None] | None = None) -> dict[str, object]:
    """Run ``suite`` under each perturbation into ``out/<name>/`` (own cache each); return name -> results table."""
    from plantbench.runner import run_suite
    from plantbench.suites import apply_override

    tables = {}
    for p in perturbations or available_perturbations():
        if on_run is not None:
            on_run(p)
        s = apply_override(suite, {f"capture.{key}": value for key, value in p.capture.items()})
        with _environment(p.env):
            result = run_suite(s, Path(out) / p.name, workers=p.workers, progress=progress)
        tables[p.name] = result.table
    return tables


def input_noise_against_grey(study, metrics: tuple[str, ...] | None = None, *, pool_clouds: bool = True):
    """Per (method, metric): the largest |change| from the reference over the cells (the cases and the mean) under
    each run of :data:`INPUT_RUNS` and under the grey-level runs together, and whether the former stay within the
    latter ('within'). With ``pool_clouds`` a method's cells on the mvs stage's oracle cloud (``NAME@oracle``) count
    as its own: the grey-level noise never reaches the oracle cloud (exact depth), so on its own that cloud has no
    noise to be held to. Methods whose input no run of INPUT_RUNS touches (a views method) show 0 there. Empty when
    the study has no such runs."""
    import pandas as pd

    from plantbench.metrics.info import HEADLINE

    metrics = HEADLINE if metrics is None else metrics
    names = [n for n in INPUT_RUNS if n in set(study["perturbation"])]
    grey = [n for n in GREY_RUNS if n in set(study["perturbation"])]
    if not names or not grey:
        return pd.DataFrame()
    if pool_clouds:
        cloud = study["method"].str.partition("@")[2]
        study = study.assign(method=study["method"].str.partition("@")[0],
                             case=study["case"] + cloud.where(cloud == "", "@" + cloud))
    ref = study[study["perturbation"] == "reference"].set_index(["method", "case", "metric"])["value"]

    def largest(runs):
        run = study[study["perturbation"].isin(runs) & study["metric"].isin(metrics)]
        value = run.set_index(["method", "case", "metric"])["value"]
        return (value - ref.reindex(value.index)).abs().groupby(level=["method", "metric"]).max()

    out = pd.DataFrame({"grey": largest(grey), **{n: largest([n]) for n in names}}).fillna(0.0)
    out["within"] = (out[names].max(axis=1) <= out["grey"] + 1e-12)
    return out.reset_index()


def _input_section(study) -> list[str]:
    table = input_noise_against_grey(study)
    if table.empty:
        return []
    names = [n for n in INPUT_RUNS if n in table.columns]
    bad = table[~table["within"]]
    lines = ["", "## Meaningless changes of a method's input against the grey-level noise", "",
             "Largest |change| from the reference over the cells (both clouds of a method), per method and headline "
             "metric: "
             + " / ".join(names) + " runs, then the largest of the three +-1 grey level runs. A method that moves more "
             "under a shuffled or 1e-6 m moved cloud than under image noise has a defect (docs/tuning/determinism.md).",
             "", "| method | metric | " + " | ".join(names) + " | grey level | within |", "|---|---|" + "---|" * (
                 len(names) + 2)]
    for r in table.itertuples(index=False):
        d = r._asdict()
        lines.append(f"| {d['method']} | {d['metric']} | " + " | ".join(f"{d[n]:.3g}" for n in names)
                     + f" | {d['grey']:.3g} | {'yes' if d['within'] else 'NO'} |")
    lines += ["", f"Within the grey-level noise: {int(table['within'].sum())} of {len(table)} (method, metric) pairs"
              + ("." if bad.empty else "; not: " + ", ".join(f"{a} {b}" for a, b in zip(bad["method"], bad["metric"],
                                                                                       strict=True)) + ".")]
    alone = input_noise_against_grey(study, pool_clouds=False)
    oracle = alone[alone["method"].str.contains("@")] if len(alone) else alone
    if len(oracle):
        worst = oracle.loc[oracle[names].max(axis=1).idxmax()]
        lines += ["", "A method's cells on the oracle cloud count as its own above: the grey-level noise does not reach "
                  "that cloud (exact depth), so on it alone there is no noise to hold a change to. Their largest change "
                  f"under {' / '.join(names)}: {max(float(oracle[n].max()) for n in names):.3g} "
                  f"({worst['method']} {worst['metric']})."]
    return lines


def study_markdown(study, tolerances: Tolerances, perturbations: list[Perturbation], *, header: str = "") -> str:
    """The study's report: what each run changed, how far it moved each headline metric (median and largest |change|
    from the reference over the cells), and the tolerances that follow."""
    import pandas as pd

    ref = study[study["perturbation"] == "reference"].set_index(["method", "case", "metric"])["value"]
    lines = [f"# Variability study: suite {tolerances.suite}", ""]
    if header:
        lines += [header, ""]
    lines += ["| run | what it changes |", "|---|---|"]
    lines += [f"| {p.name} | {p.description} |" for p in perturbations]
    lines += ["", "## |change| from the reference run, per headline metric (median / largest over the cells)", ""]
    names = [p.name for p in perturbations if p.name != "reference"]
    lines += ["| metric | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for metric in GATED:
        cells = []
        for name in names:
            run = study[(study["perturbation"] == name) & (study["metric"] == metric)]
            run = run.set_index(["method", "case", "metric"])["value"]
            change = (run - ref.reindex(run.index)).abs().dropna()
            cells.append("-" if change.empty else f"{change.median():.3g} / {change.max():.3g}")
        if any(c != "-" for c in cells):
            lines.append(f"| {metric} | " + " | ".join(cells) + " |")
    tol = pd.DataFrame([e.model_dump() for e in tolerances.entries])
    lines += ["", f"## Tolerances ({tolerances.rule}), per method and metric: median over cases [largest]", ""]
    methods = sorted(tol["method"].unique()) if len(tol) else []
    lines += ["| metric | floor | " + " | ".join(methods) + " |", "|---|---|" + "---|" * len(methods)]
    for metric in GATED:
        t = tol[tol["metric"] == metric] if len(tol) else tol
        if t.empty:
            continue
        cells = []
        for m in methods:
            v = t.loc[t["method"] == m, "tolerance"]
            cells.append("-" if v.empty else f"{v.median():.3g} [{v.max():.3g}]")
        lines.append(f"| {metric} | {tolerances.floors.get(metric, 0):g} | " + " | ".join(cells) + " |")
    if len(tol):
        bound = tol["bound"].value_counts()
        lines += ["", "Cells whose tolerance is set by each term: "
                  + ", ".join(f"{k} {int(bound.get(k, 0))}" for k in ("spread", "max_change", "floor"))
                  + f" (of {len(tol)})."]
        flaky = tol[tol["may_fail"]] if "may_fail" in tol else tol.iloc[:0]
        if len(flaky):
            cells = sorted({f"{m} {c}" for m, c in zip(flaky["method"], flaky["case"], strict=True)})
            lines += ["", f"Cells that failed in a run of the study (the gate does not count their failing as a "
                      f"regression): {', '.join(cells)}."]
    lines += _input_section(study)
    return "\n".join(lines) + "\n"


def read_study(path: Path):
    """A committed study table (study.csv), checked for its columns and a reference run."""
    import pandas as pd

    from plantbench.errors import InputError

    path = Path(path)
    if not path.is_file():
        raise InputError("no study to add to: run `plantbench variability` on the first machine", path=path)
    try:
        study = pd.read_csv(path)
    except (OSError, ValueError) as exc:
        raise InputError(f"unreadable study table: {exc}", path=path) from None
    if list(study.columns) != STUDY_COLUMNS or "reference" not in set(study["perturbation"]):
        raise InputError(f"not a study table (columns {STUDY_COLUMNS} and a 'reference' run)", path=path)
    return study


def _made_line(folder: Path, suite: str, chosen: list[Perturbation], previous, seconds: float, meta: dict) -> str:
    """The study README's header: how it was made; with ``previous`` (an --another-cpu run) the first machine's
    header stays and this run is added below it."""
    from plantbench.backend import host_cpu_name

    if previous is None:
        return (f"Made by `plantbench variability --suite {suite}` on {host_cpu_name()} (code {meta.get('git_sha')}, "
                f"{seconds:.0f} s for {len(chosen)} runs). study.csv holds every run's headline values; "
                "../tolerances.json the tolerances; ../baseline.json the reference run's values.")
    lines = (folder / "README.md").read_text().splitlines() if (folder / "README.md").is_file() else []
    end = next((i for i, line in enumerate(lines) if line.startswith("| run |")), len(lines))
    old = "\n".join(line for line in lines[1:end] if not line.startswith(f"Run {chosen[0].name} ")).strip()
    return (f"{old}\n\nRun {chosen[0].name} added by `plantbench variability --suite {suite} --another-cpu` on "
            f"{host_cpu_name()} (code {meta.get('git_sha')}, {seconds:.0f} s).")


def write_study(reports: Path, suite: str, tables: dict[str, object], chosen: list[Perturbation], *, previous=None,
                seconds: float = 0.0, meta: dict | None = None) -> list[Path]:
    """Write a study's outputs under ``reports``: variability/study.csv (``previous`` grown by ``tables`` when given),
    variability/README.md, tolerances.json and, for a first study (no ``previous``), baseline.json from the
    reference run. ``meta`` is the first run's run.json (git SHA, Dr.Jit target). Returns the files written."""
    from plantbench.io.atomic import atomic_write
    from plantbench.report.gate import make_baseline, write_baseline, write_tolerances

    meta = meta or {}
    reports = Path(reports)
    folder = reports / "variability"
    study = study_table(tables) if previous is None else extend_study(previous, tables)
    tol = tolerances_from_study(study, suite)
    folder.mkdir(parents=True, exist_ok=True)
    with atomic_write(folder / "study.csv", "w") as fh:
        study.to_csv(fh, index=False)
    made = _made_line(folder, suite, chosen, previous, seconds, meta)
    with atomic_write(folder / "README.md", "w") as fh:
        fh.write(study_markdown(study, tol, study_perturbations(study), header=made))
    write_tolerances(reports / "tolerances.json", tol)
    written = [folder / "study.csv", folder / "README.md", reports / "tolerances.json"]
    if previous is None:
        write_baseline(reports / "baseline.json", make_baseline(tables["reference"], suite,
                                                                llvm_target=meta.get("llvm_target"),
                                                                git_sha=meta.get("git_sha")))
        written.append(reports / "baseline.json")
    return written

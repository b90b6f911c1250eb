"""Commands on one case: ``generate``, ``capture``, ``reconstruct``, ``evaluate``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from plantbench.commands._app import _emit, app
from plantbench.errors import InputError


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
    option: Annotated[Optional[list[str]], typer.Option(  # noqa: UP045
        "--option", help="NAME=VALUE, repeatable: a method option, as a suite's [method_options] table sets it "
                         "(`plantbench methods NAME` lists them); VALUE is read as TOML (3, 0.5, true, [5, 45]), "
                         "else as text.")] = None,
) -> None:
    """Run one method on one case, on the same input folder the runner prepares (only what a real capture gives,
    plus the species hint)."""
    from plantbench.methods.api import method_from_spec
    from plantbench.methods.inputs import run_isolated
    from plantbench.methods.options import parse_options

    m = method_from_spec(method)
    options = parse_options(option)
    if hasattr(m, "check_options"):  # before any work, as the planner does: a did-you-mean for an unknown name
        m.check_options(options)
    if not case.is_dir():
        raise InputError("case folder not found", path=case)
    run_isolated(m, case, out, seed=seed, species=species, points_dir=points, options=options)
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

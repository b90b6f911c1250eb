"""``plantbench qsm``: QSM cylinder tables to and from skeletons."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from plantbench.commands._app import _group

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

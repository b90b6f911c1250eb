"""``plantbench import``: real captures in (a scan file, photos with a COLMAP model)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from plantbench.commands._app import _group

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

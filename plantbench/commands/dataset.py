"""``plantbench dataset``: frozen datasets (pack, verify)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from plantbench.commands._app import _group

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

"""Frozen datasets: pack a suite, run from the pack (same results table as the direct run), and every way a pack
can be damaged is an error naming the file."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import pandas as pd
import pytest

from plantbench.dataset import file_sha256, manifest_sha256, pack_suite, verify_dataset
from plantbench.errors import InputError
from plantbench.runner import run_suite
from plantbench.suites import load_suite
from tests.runner.conftest import suite_toml


@pytest.fixture(scope="module")
def packed(tmp_path_factory):
    """(suite, direct run, dataset folder): a two-case suite run directly, then packed from a fresh cache."""
    base = tmp_path_factory.mktemp("dataset")
    suite = load_suite(str(suite_toml(base / "frozen.toml", ["gt"], seeds=(1, 2))))
    direct = run_suite(suite, base / "direct", workers=2)
    manifest = pack_suite(suite, base / "pack", cache=base / "pack-cache", workers=2)
    assert len(manifest.cases) == 2
    return suite, direct, base / "pack"


def test_manifest_lists_every_file_with_its_hash(packed):
    _, _, pack = packed
    manifest = json.loads((pack / "manifest.json").read_text())
    files = sorted(str(p.relative_to(pack)) for p in (pack / "cases").rglob("*") if p.is_file())
    assert sorted(manifest["files"]) == files
    some = files[len(files) // 2]
    assert manifest["files"][some] == file_sha256(pack / some)
    assert {c["id"] for c in manifest["cases"]} == {"laurel-1", "laurel-2"}
    for case in ("laurel-1", "laurel-2"):
        for part in ("plant/plant.json", "plant/skeleton.ply", "views/cameras.json", "views/images/0000.png",
                     "scan/scan.ply"):
            assert f"cases/{case}/{part}" in manifest["files"]
    assert manifest["code"]["generate"] and manifest["code"]["capture"] and manifest["licence"]
    assert manifest["llvm_target"] and "Datasheet" in (pack / "DATASHEET.md").read_text()
    assert not list(pack.parent.glob(".pack.*"))  # no temporary folder left behind


def test_run_from_the_dataset_gives_the_direct_runs_table(packed, tmp_path):
    suite, direct, pack = packed
    frozen = run_suite(suite, tmp_path / "runs", workers=2, dataset=pack)
    cols = ["case", "method", "metric", "value", "status"]
    a = direct.table[direct.table["metric"] != "runtime_s"][cols].sort_values(cols[:3]).reset_index(drop=True)
    b = frozen.table[frozen.table["metric"] != "runtime_s"][cols].sort_values(cols[:3]).reset_index(drop=True)
    assert len(a) > 20
    pd.testing.assert_frame_equal(a, b)
    meta = json.loads((frozen.run_dir / "run.json").read_text())
    assert meta["dataset"]["manifest_sha256"] == manifest_sha256(pack)
    from plantbench.report.report import provenance

    assert manifest_sha256(pack) in provenance(frozen.run_dir)  # the report's header line
    # nothing was generated or rendered: the captures are copies of the dataset's
    stats = frozen.stats["by_kind"]
    assert "plant" not in stats and stats["capture"]["computed"] == 2


@pytest.mark.parametrize("damage", ["flip", "delete", "add"])
def test_a_damaged_dataset_names_the_file(packed, tmp_path, damage):
    suite, _, pack = packed
    copy = tmp_path / "copy"
    shutil.copytree(pack, copy)
    image = copy / "cases" / "laurel-2" / "views" / "images" / "0001.png"
    if damage == "flip":
        data = bytearray(image.read_bytes())
        data[len(data) // 2] ^= 0x01
        image.write_bytes(bytes(data))
        target, why = image, "corrupted"
    elif damage == "delete":
        image.unlink()
        target, why = image, "missing"
    else:
        target, why = copy / "cases" / "laurel-1" / "views" / "oracle.npy", "not in manifest.json"
        target.write_bytes(b"x")
    with pytest.raises(InputError, match=why) as err:
        verify_dataset(copy)
    assert str(target) in str(err.value)
    with pytest.raises(InputError, match=why):
        run_suite(suite, tmp_path / "runs", dataset=copy)
    assert not (tmp_path / "runs" / "cache").exists()  # refused before any work
    # the CLI: one line naming the file, exit 2
    cli = subprocess.run([sys.executable, "-m", "plantbench.cli", "dataset", "verify", str(copy)],
                         capture_output=True, text=True)
    assert cli.returncode == 2 and str(target) in cli.stdout + cli.stderr


def test_pack_refuses_to_overwrite_and_a_suite_that_differs(packed, tmp_path):
    suite, _, pack = packed
    with pytest.raises(InputError, match="already exists"):
        pack_suite(suite, pack, cache=tmp_path / "cache")
    from plantbench.suites import apply_override

    other = apply_override(suite, {"capture.views": 3})
    with pytest.raises(InputError, match="capture differ"):
        run_suite(other, tmp_path / "runs", dataset=pack)

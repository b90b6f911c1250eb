"""End-to-end runner behaviour on a tiny suite: failures become cells, caching, resume after SIGINT, Dask."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest

from plantbench.errors import InputError
from plantbench.runner import run_suite
from plantbench.suites import load_suite
from tests.runner.conftest import suite_toml


def _status(table: pd.DataFrame, method: str) -> set[str]:
    return set(table.loc[table["method"] == method, "status"])


def test_failures_become_cells_and_rerun_reuses_everything(tmp_path, scripts):
    methods = ["gt", scripts["crash"], scripts["sleep"], scripts["empty"]]
    suite = load_suite(str(suite_toml(tmp_path / "tiny.toml", methods, timeout_s=20)))
    res = run_suite(suite, tmp_path / "runs", workers=2)
    t = res.table
    assert _status(t, "gt") == {"ok"}
    gt = t[(t["method"] == "gt")].set_index("metric")["value"]
    assert gt["stava.S_T"] == pytest.approx(1.0)
    assert _status(t, scripts["crash"]) == {"failed"}
    assert _status(t, scripts["sleep"]) == {"timeout"}
    assert _status(t, scripts["empty"]) == {"invalid"}
    # every failed cell keeps its log, and the log says why
    logs = {p.name: p.read_text() for p in (res.run_dir / "logs").iterdir()}
    assert any("method exploded on purpose" in text for text in logs.values())
    assert len(logs) == 3
    # every job's status records when it ran (the run's timeline); the sleeper ran its whole timeout
    recs = [json.loads(f.read_text()) for f in (tmp_path / "runs" / "cache").glob("*/*/status.json")]
    assert recs and all(r["started"] <= r["finished"] for r in recs)
    sleeper = next(r for r in recs if r["status"] == "timeout")
    assert sleeper["finished"] - sleeper["started"] >= 20
    # the tidy table and metadata are on disk
    disk = pd.read_parquet(res.run_dir / "results.parquet")
    assert list(disk.columns) == ["case", "species", "family", "seed", "method", "sweep", "metric", "value", "status"]
    meta = json.loads((res.run_dir / "run.json").read_text())
    for key in ("plantbench_version", "git_sha", "config_hash", "packages", "mitsuba_variant"):
        assert key in meta
    # cells.json points at each cell's capture and reconstruction; the report draws gt from them
    cells = json.loads((res.run_dir / "cells.json").read_text())
    assert sorted(c["method"] for c in cells) == sorted(methods)
    gt_cell = next(c for c in cells if c["method"] == "gt")
    assert gt_cell["status"] == "ok" and (res.run_dir / gt_cell["recon"] / "skeleton.ply").is_file()
    assert (res.run_dir / gt_cell["capture"] / "plant" / "plant.json").is_file()
    from plantbench.report.report import distance_figure

    png = distance_figure(res.run_dir, tmp_path / "distances.png")
    assert png is not None and png.stat().st_size > 1000
    # timeline.csv: one row per job with the times its status.json holds; the report draws it
    timeline = pd.read_csv(res.run_dir / "timeline.csv")
    ran = timeline[timeline["started"].notna()]
    assert len(timeline) == len(recs) + 3 and set(ran["key"]) == {r["key"] for r in recs}  # 3 skipped: no times
    by_key = {r["key"]: r for r in recs}
    assert all(row.started == by_key[row.key]["started"] and row.status == by_key[row.key]["status"]
               for row in ran.itertuples())
    assert set(timeline["job"]) >= {"plant", "capture", "gt", "metrics"} and not timeline["reused"].any()
    from plantbench.report.report import timeline_figure

    png = timeline_figure(res.run_dir, tmp_path / "timeline.png")
    assert png is not None and png.stat().st_size > 1000
    # a second run recomputes nothing
    again = run_suite(suite, tmp_path / "runs", workers=2)
    assert again.stats["computed"] == 0 and again.stats["reused"] == res.stats["computed"] + res.stats["reused"]
    assert again.stats["skipped"] == res.stats["skipped"] == 3  # metrics of the three failed cells
    pd.testing.assert_frame_equal(
        again.table.drop(columns="value"), res.table.drop(columns="value"), check_like=True
    )


def test_sigint_then_resume_recomputes_nothing_finished(tmp_path, scripts):
    toml = suite_toml(tmp_path / "resume.toml", [scripts["slow_ok"]], seeds=(1, 2, 3, 4), timeout_s=120)
    out = tmp_path / "runs"
    cmd = [sys.executable, "-m", "plantbench.cli", "run", "--suite", str(toml), "--out", str(out)]
    # a shell that starts the tests in the background (`make test &`) leaves SIGINT ignored, and Python then never
    # raises KeyboardInterrupt: give the run the default disposition, as an interactive terminal would
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    method_dir = out / "cache" / "method"
    deadline = time.time() + 240
    # interrupt once at least one method cell (1.5 s each) has finished but not all four
    while time.time() < deadline:
        done = [p for p in method_dir.glob("[!.]*") if (p / "status.json").exists()] if method_dir.exists() else []
        if done:
            break
        time.sleep(0.1)
    assert done, "no method cell finished in time"
    proc.send_signal(signal.SIGINT)
    output, _ = proc.communicate(timeout=120)
    assert proc.returncode == 130, output
    assert "resume" in output
    finished = {p.name: (p / "status.json").stat().st_mtime_ns for p in method_dir.iterdir() if not p.name.startswith(".")}
    assert 1 <= len(finished) < 4
    assert not [p for p in method_dir.iterdir() if p.name.endswith(".tmp")], "temporary folders left behind"
    res = run_suite(load_suite(str(toml)), out)
    assert set(res.table["status"]) == {"ok"}
    # the cells finished before the interrupt were reused, untouched
    for name, mtime in finished.items():
        assert (method_dir / name / "status.json").stat().st_mtime_ns == mtime
    assert res.stats["by_kind"]["method"]["reused"] == len(finished)
    assert res.stats["by_kind"]["method"]["computed"] == 4 - len(finished)


def test_dask_local_cluster_gives_the_same_table(tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    toml = suite_toml(tmp_path / "dask.toml", ["gt"], seeds=(1, 2))
    suite = load_suite(str(toml))
    local = run_suite(suite, tmp_path / "local", workers=1)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        with distributed.Client(cluster) as client:
            remote = run_suite(suite, tmp_path / "dask", executor="dask", client=client)
    assert remote.stats["computed"] == local.stats["computed"]
    keep = local.table["metric"] != "runtime_s"
    a = local.table[keep].reset_index(drop=True)
    b = remote.table[remote.table["metric"] != "runtime_s"].reset_index(drop=True)
    pd.testing.assert_frame_equal(a, b)


def test_unknown_species_fails_before_any_work(tmp_path):
    from plantbench.errors import UnknownNameError

    toml = suite_toml(tmp_path / "bad.toml", ["gt"], species="lauurel")
    with pytest.raises(UnknownNameError, match="did you mean 'laurel'"):
        run_suite(load_suite(str(toml)), tmp_path / "runs")
    assert not (tmp_path / "runs" / "cache").exists()




def test_points_input_links_the_mvs_depth_maps(tmp_path):
    """A 'points' method's input folder holds the mvs cloud, the capture's views and, when the mvs stage wrote them
    (write_depth), its depth maps (guo's leaves='segment' reads them)."""
    from plantbench.runner.worker import _points, job_folder

    cache = tmp_path / "cache"
    case = job_folder(cache, "capture", "c0")
    (case / "views").mkdir(parents=True)
    recon = job_folder(cache, "method", "m0")
    (recon / "depth").mkdir(parents=True)
    np.savez_compressed(recon / "depth" / "0000.npz", depth=np.ones((2, 2), np.float32))
    (recon / "points.ply").write_bytes(b"ply\n")
    for with_depth in (True, False):
        folder = tmp_path / f"in{with_depth}"
        folder.mkdir()
        if not with_depth:
            import shutil

            shutil.rmtree(recon / "depth")
        _points(cache, folder, {"case": "c0", "source": "views", "recon": "m0"})
        assert (folder / "views").is_dir() and (folder / "points.ply").read_bytes() == b"ply\n"
        assert (folder / "depth").exists() == with_depth
        if with_depth:
            assert np.load(folder / "depth" / "0000.npz")["depth"].shape == (2, 2)


def test_misspelt_method_options_fail_when_the_suite_is_loaded(tmp_path):
    """A typo in [method_options.NAME] stops `plantbench run` before any job, naming the suite file, the method
    and the option, with a did-you-mean."""
    from plantbench.cli import main
    from plantbench.suites import load_suite

    base = 'name = "typo"\ndescription = "x"\nmethods = ["guo", "mvs"]\n[[cases]]\nspecies = "laurel"\nseeds = [1]\n'
    cases = {
        "[method_options.guo]\nkil_factor = 0.5\n": ("[method_options.guo]", "'kil_factor'", "'kill_factor'"),
        "[method_options.guo]\nleaves = 'combined'\nleaf__min_view = 2\n": ("[method_options.guo]",
                                                                            "'leaf__min_view'", "'leaf__min_views'"),
        "[method_options.mvs]\ndepth_params__hypothesis = 64\n": ("[method_options.mvs]", "'depth_params__hypothesis'",
                                                                  "'depth_params__hypotheses'"),
        "[method_options.lvny]\nvoxel = 1\n": ("[method_options.lvny]", "'lvny'", "'livny'"),
    }
    for i, (table, words) in enumerate(cases.items()):
        path = tmp_path / f"typo{i}.toml"
        path.write_text(base + table)
        with pytest.raises(InputError) as info:
            load_suite(str(path))
        msg = str(info.value)
        assert msg.startswith(str(path)) and all(w in msg for w in words) and "did you mean" in msg
        assert main(["run", "--suite", str(path), "--out", str(tmp_path / "runs")]) == 2
    assert not (tmp_path / "runs").exists()  # nothing planned, nothing captured

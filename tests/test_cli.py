"""The CLI as a user sees it: exit codes and one-line errors, in a subprocess."""

import os
import subprocess
import sys

import pytest


def plantbench(*args, **kw):
    return subprocess.run([sys.executable, "-m", "plantbench.cli", *args], capture_output=True, text=True, **kw)


def test_help_lists_every_subcommand():
    out = plantbench("--help")
    assert out.returncode == 0
    for cmd in ("generate", "capture", "reconstruct", "evaluate", "run", "report", "gate", "species", "suites",
                "methods"):
        assert cmd in out.stdout
        sub = plantbench(cmd, "--help")
        assert sub.returncode == 0, (cmd, sub.stderr)


def test_unknown_suite_did_you_mean():
    out = plantbench("run", "--suite", "quik")
    assert out.returncode == 2
    assert "did you mean 'quick'" in out.stderr
    assert "Traceback" not in out.stderr and len(out.stderr.strip().splitlines()) == 1


def test_debug_shows_traceback():
    out = plantbench("--debug", "run", "--suite", "quik")
    assert out.returncode != 0 and "Traceback" in out.stderr


def test_unknown_method_did_you_mean(tmp_path):
    out = plantbench("reconstruct", str(tmp_path), "--method", "gtt", "--out", str(tmp_path / "o"))
    assert out.returncode == 2 and "did you mean 'gt'" in out.stderr


def test_malformed_suite_file_names_file(tmp_path):
    bad = tmp_path / "mine.toml"
    bad.write_text("name = [\n")
    out = plantbench("run", "--suite", str(bad))
    assert out.returncode == 2 and "mine.toml: malformed TOML" in out.stderr


@pytest.mark.parametrize("cmd", [["methods"], ["suites"], ["species"]])
def test_listings(cmd):
    out = plantbench(*cmd)
    assert out.returncode == 0, out.stderr


def test_methods_lists_gt():
    assert "gt" in plantbench("methods").stdout


def test_external_command_needs_out_placeholder(tmp_path):
    out = plantbench("reconstruct", str(tmp_path), "--method", "cmd:echo {capture}", "--out", str(tmp_path / "o"))
    assert out.returncode == 2 and "{out}" in out.stderr


def test_compare_two_runs_in_a_pipe(tmp_path):
    import pandas as pd

    for name, shift in (("a", 0.0), ("b", 0.1)):
        (tmp_path / name).mkdir()
        pd.DataFrame([{"case": f"c{i}", "species": "s", "family": "f", "seed": 1, "method": "guo", "sweep": None,
                       "metric": metric, "value": 0.3 + 0.01 * i + shift, "status": "ok"}
                      for i in range(5) for metric in ("skeleton.vf1@1%", "skeleton.lprecision@1%")]).to_csv(tmp_path / name / "results.csv", index=False)
    out = plantbench("compare", str(tmp_path / "a"), str(tmp_path / "b"), "--label-a", "mvs", "--label-b", "oracle",
                     "--out", str(tmp_path / "cmp.csv"))
    assert out.returncode == 0, out.stderr
    row = next(line for line in out.stdout.splitlines() if "skeleton.vf1@1%" in line)
    assert "| guo |" in row and "+0.100 [+0.100, +0.100]" in row and "oracle better" in row
    assert "\x1b[" not in out.stdout  # plain text into a pipe
    assert pd.read_csv(tmp_path / "cmp.csv")["verdict"].tolist() == ["oracle better"]  # the key metrics only
    same = plantbench("compare", str(tmp_path / "a"), str(tmp_path / "b"), "--label-a", "x", "--label-b", "x")
    assert same.returncode == 2 and "must differ" in same.stderr
    # --metric picks the rows; a misspelt one is one line naming the option, with the registered name it meant
    one = plantbench("compare", str(tmp_path / "a"), str(tmp_path / "b"), "--metric", "skeleton.lprecision@1%")
    assert one.returncode == 0, one.stderr
    assert "skeleton.lprecision@1%" in one.stdout and "skeleton.vf1@1%" not in one.stdout
    bad = plantbench("compare", str(tmp_path / "a"), str(tmp_path / "b"), "--metric", "skeleton.lprecison@1%")
    assert bad.returncode == 2 and "--metric" in bad.stderr and "'skeleton.lprecision@1%'" in bad.stderr


def test_capture_flags_are_the_capture_settings(tmp_path):
    """`plantbench capture`'s flags are generated from CaptureOptions: every field has one, with its description;
    an invalid value is one line naming the setting (exit 2) and writes nothing."""
    from plantbench.capture.settings import CaptureOptions

    out = plantbench("capture", "--help", env={**os.environ, "COLUMNS": "200"})
    assert out.returncode == 0
    for name in CaptureOptions.model_fields:
        assert "--" + name.replace("_", "-") in out.stdout, name
    assert "--no-scan" in out.stdout and "--seed" in out.stdout
    (tmp_path / "case").mkdir()
    bad = plantbench("capture", str(tmp_path / "case"), "--views", "0")
    assert bad.returncode == 2 and "views" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1
    assert not any((tmp_path / "case").iterdir())


def test_progress_bar_only_on_a_terminal():
    """Into a pipe or a file the progress bar is a plain line per tenth of the work (no bar characters in a log); on
    a terminal it draws."""
    import io

    from rich.console import Console

    from plantbench.commands._app import _progress_bar

    def drawn(terminal: bool) -> str:
        buf = io.StringIO()
        console = Console(file=buf, force_terminal=terminal, width=80)
        with _progress_bar(console) as bar:
            task = bar.add_task("suite quick", total=20)
            for _ in range(20):
                bar.advance(task)
        return buf.getvalue()

    plain = drawn(False).splitlines()
    assert [line.split(",")[0] for line in plain] == [f"suite quick: {k}/20" for k in range(2, 21, 2)], plain
    assert "━" in drawn(True) and "20/20" in drawn(True)

"""The ``gonio sweep`` and ``gonio bench`` command lines."""

from __future__ import annotations

import json
import re
import sys

import pytest

from gonio.cli import main

TOML = """name = "cli"
task = "fit_preset"
materials = ["rolled_brass"]
seeds = 2
[settings]
noise = [0.01, 0.1]
[fixed]
n_samples = 60
"""


def test_sweep_cli_runs_and_skips(tmp_path, capsys):
    spec = tmp_path / "s.toml"
    spec.write_text(TOML)
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "-o", str(out), "--json", str(tmp_path / "r.json")]) == 0
    text = capsys.readouterr()
    assert "4/4 task(s) done (4 run, 0 skipped) on inprocess" in text.out
    assert re.search(r"results in \S+ \(\d+\.\d MB; raw frames of the tasks run: none\)", text.out)
    assert "rms_log_brdf_mean" in text.out
    assert "[4/4]" in text.err
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["n_tasks"] == 4 and doc["executor"] == "inprocess" and doc["failures"] == {}
    assert {r["noise"] for r in doc["rows"]} == {0.01, 0.1}
    assert (out / "summary.png").is_file() and (out / "results.csv").is_file()
    assert (
        main(["sweep", str(spec), "-o", str(out), "-q", "--processes", "2", "--raw", "keep"]) == 0
    )
    text = capsys.readouterr().out
    assert "(0 run, 4 skipped) on process" in text and "tasks run: keep)" in text


def test_sweep_cli_dry_run(tmp_path, capsys):
    spec = tmp_path / "s.toml"
    spec.write_text(TOML)
    assert main(["sweep", str(spec), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "4 task(s) of 'fit_preset'" in out and "rolled_brass-s1-" in out
    assert not (tmp_path / "sweep_cli").exists()


def test_sweep_cli_bad_spec(tmp_path, capsys):
    spec = tmp_path / "s.toml"
    spec.write_text(TOML.replace("seeds = 2", "seeds = -1"))
    assert main(["sweep", str(spec)]) == 2
    err = capsys.readouterr().err
    assert "gonio sweep: error: sweep spec" in err
    assert "'seeds' as a count must be in [1, 100000]" in err
    assert main(["sweep", str(tmp_path / "none.toml")]) == 2
    assert "does not exist" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # argparse: mutually exclusive executors
        main(["sweep", str(spec), "--processes", "2", "--dask-local", "2"])


def test_sweep_cli_without_dask(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)
    spec = tmp_path / "s.toml"
    spec.write_text(TOML)
    assert main(["sweep", str(spec), "-o", str(tmp_path / "o"), "--dask-local", "2"]) == 2
    assert "pip install 'gonio[distributed]'" in capsys.readouterr().err
    assert main(["sweep", str(spec), "-o", str(tmp_path / "o"), "--scheduler", "tcp://x:1"]) == 2
    assert "dask[distributed]" in capsys.readouterr().err


def test_bench_cli_quick(tmp_path, capsys):
    args = ["bench", "--quick", "--knob", "noise_level", "--knob", "rays_per_pixel"]
    files = ["--json", str(tmp_path / "b.json"), "--csv", str(tmp_path / "b.csv")]
    assert main([*args, *files, "--plot", str(tmp_path / "p.png")]) == 0
    out = capsys.readouterr().out
    assert "noise_level" in out and "ablations" in out
    doc = json.loads((tmp_path / "b.json").read_text())
    waiting = any(not k["available"] for k in doc["knobs"].values())
    assert ("knobs not yet available" in out) == waiting
    assert [r["setting"] for r in doc["rows"] if r["knob"] == "noise_level"] == [0.0, 0.1]
    assert doc["knobs"]["noise_level"]["available"] is True
    assert doc["knobs"]["rays_per_pixel"]["available"] in (True, False)
    assert {a["name"] for a in doc["ablations"]} >= {"geometry_cache", "visible_pixel_mask"}
    assert (tmp_path / "b.csv").read_text().startswith("knob,setting,seed,time_s")
    assert (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"
    assert main(["bench", "--knob", "nope"]) == 2
    assert "unknown knob 'nope'" in capsys.readouterr().err
    assert main(["bench", "--list"]) == 0
    assert "albedo_rtol" in capsys.readouterr().out


class _Terminal:
    """A stderr that says it is a terminal (the sweep's bar is drawn only on one)."""

    def __init__(self) -> None:
        self.text = ""

    def write(self, s: str) -> int:
        self.text += s
        return len(s)

    def flush(self) -> None:
        pass

    def isatty(self) -> bool:
        return True


def test_sweep_cli_progress_on_a_terminal_not_when_quiet(tmp_path, monkeypatch, capsys):
    spec = tmp_path / "s.toml"
    spec.write_text(TOML.replace("seeds = 2", "seeds = 1"))
    term = _Terminal()
    monkeypatch.setattr(sys, "stderr", term)
    assert main(["sweep", str(spec), "-o", str(tmp_path / "a"), "--no-plot"]) == 0
    assert "sweep cli [" in term.text  # the bar, with its own label
    assert "0/2 0.0 s, ? left" in term.text  # before the first task ends
    assert re.search(r"2/2 \d+\.\d s, 0 s left", term.text)  # done/total, elapsed, left
    assert re.search(r"\[2/2\] rolled_brass-s0-\w+: \d", term.text)  # per-task lines
    term.text = ""
    assert main(["sweep", str(spec), "-o", str(tmp_path / "b"), "--no-plot", "-q"]) == 0
    assert term.text == ""
    capsys.readouterr()


def test_sweep_time_left_reads_in_its_unit():
    from gonio.cli.sweep import _time_left

    assert _time_left(10.0, 0, 4) == "? left" and _time_left(10.0, 2, 0) == "0 s left"
    assert _time_left(10.0, 2, 3) == "~15 s left"
    assert _time_left(100.0, 2, 3) == "~2.5 min left"
    assert _time_left(3600.0, 1, 2) == "~2.0 h left"

"""Children and temporaries of a command cleaned on SIGTERM (issue 30, 8): ``export bsdf``
stopped while ``pabopto2bsdf`` runs leaves neither its temporary folder nor the program."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from tests.cli.test_export import _samples  # a samples table


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as f:  # a zombie is gone for good
        return f.read().split(")")[-1].split()[0] != "Z"


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_export_bsdf_stopped_by_a_signal_leaves_no_temporary_or_child(tmp_path, sig):
    table = _samples(tmp_path)
    slow = tmp_path / "pabopto2bsdf"
    slow.write_text(f"#!/bin/sh\necho $$ > {tmp_path}/child.pid\nexec sleep 60\n")
    slow.chmod(0o755)
    # (SIGINT as a terminal's foreground process has it: a process started in the background
    # by a non-interactive shell, as a CI script may start the suite, inherits it ignored)
    script = textwrap.dedent(f"""
        import signal
        signal.signal(signal.SIGINT, signal.default_int_handler)
        import gonio.io.radiance as r
        r.radiance_tool = lambda name: {str(slow)!r}
        from gonio.cli import main
        raise SystemExit(main(["export", "bsdf", {str(table)!r}, {str(tmp_path / "out")!r}]))
    """)
    # (cwd: not the checkout, whose gonio/ would shadow the installed package's layout)
    p = subprocess.Popen([sys.executable, "-c", script], stderr=subprocess.PIPE, cwd=tmp_path)
    pid_file = tmp_path / "child.pid"
    t0 = time.monotonic()
    while not pid_file.exists() or not pid_file.read_text().strip():
        assert time.monotonic() - t0 < 60 and p.poll() is None, p.stderr.read()
        time.sleep(0.05)
    child = int(pid_file.read_text())
    assert any(d.name.startswith("gonio_bsdf_") for d in (tmp_path / "out").iterdir())
    p.send_signal(sig)
    assert p.wait(timeout=30) == 130
    time.sleep(0.2)
    assert not _alive(child)
    assert not [d for d in (tmp_path / "out").iterdir() if d.name.startswith("gonio_bsdf_")]


def test_sweep_stopped_by_sigterm_cancels_its_tasks_and_ends_its_workers(tmp_path):
    """(It ran every queued task to the end before exiting, its workers then idle.)"""
    import psutil

    spec = tmp_path / "s.toml"
    spec.write_text('task = "campaign"\nmaterials = ["rolled_brass"]\nseeds = 6\n'
                    "[fixed]\ntheta_i_deg = [30.0, 40.0]\n")  # fmt: skip
    argv = ["sweep", str(spec), "--processes", "2", "--out", str(tmp_path / "out"), "-q"]
    code = f"import sys; from gonio.cli import main; sys.exit(main({argv!r}))"
    p = subprocess.Popen([sys.executable, "-c", code], stderr=subprocess.PIPE, cwd=tmp_path)
    proc = psutil.Process(p.pid)
    t0 = time.monotonic()
    while len(proc.children()) < 2:
        assert time.monotonic() - t0 < 60 and p.poll() is None
        time.sleep(0.05)
    workers = proc.children()
    time.sleep(1.0)
    p.send_signal(signal.SIGTERM)
    assert p.wait(timeout=20) == 130
    _gone, alive = psutil.wait_procs(workers, timeout=5)
    assert not alive
    done = list((tmp_path / "out").glob("tasks/*/sweep_task.json"))
    assert len(done) < 6  # the queued tasks were cancelled, not run

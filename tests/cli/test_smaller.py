"""Smaller failures of issue 30 (9): a deleted working directory with a relative output path;
a parameter given twice (``--fixed P=a --fixed P=b``) or fixed and started at once."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from gonio.cli import main


def test_a_relative_out_in_a_deleted_working_directory_is_a_clear_error(tmp_path):
    gone = tmp_path / "gone"
    gone.mkdir()
    script = textwrap.dedent(f"""
        import os
        os.chdir({str(gone)!r})
        os.rmdir({str(gone)!r})
        from gonio.cli import main
        raise SystemExit(main(["campaign", "--angles", "30", "--out", "rel"]))
    """)
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert "working directory no longer exists" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize(
    "argv, match",
    [
        (["--fixed", "rho_d=0.1", "--fixed", "rho_d=0.2"], "--fixed rho_d is given twice"),
        (["--fixed", "rho_d", "--fixed", "rho_d=0.2"], "--fixed rho_d is given twice"),
        (["--init", "rho_d=0.1", "--init", "rho_d=0.2"], "--init rho_d is given twice"),
        (["--fixed", "rho_d=0.1", "--init", "rho_d=0.2"], "held by --fixed at a value"),
    ],
)
def test_a_parameter_given_twice_is_refused(tmp_path, capsys, argv, match):
    (tmp_path / "x.csv").write_text("")
    assert main(["fit", str(tmp_path / "x.csv"), "--model", "ward", *argv]) == 2
    assert match in capsys.readouterr().err


def test_render_and_export_param_given_twice(tmp_path, capsys):
    out = tmp_path / "a.png"
    argv = ["render", "--model", "ward", "--param", "rho_d=0.1", "--param", "rho_d=0.2"]
    assert main([*argv, "--out", str(out)]) == 2
    assert "given twice" in capsys.readouterr().err and not out.exists()
    argv = ["export", "material", str(tmp_path / "m"), "--model", "ward", "--param", "rho_d=0.1"]
    assert main([*argv, "--param", "rho_d=0.3"]) == 2
    assert "given twice" in capsys.readouterr().err
    assert not os.path.exists(tmp_path / "m" / "material.rad")

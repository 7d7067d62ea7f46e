"""Messages in the syntax of the interface that prints them (issue 32): the library's hints
in Python keyword syntax, the command line's in option syntax."""

import numpy as np
import pytest

from gonio.cli import build_parser, main
from gonio.cli._common import option_map
from gonio.hints import as_options, keyword


def _subparser(name: str):
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    return sub.choices[name]


def test_keyword_hints_render_as_the_commands_options():
    fit_opts = option_map(_subparser("fit"))
    assert fit_opts["n_starts"] == "--starts" and fit_opts["fixed"] == "--fixed"
    text = f"try {keyword('n_starts')} or {keyword('init')}; fix some ({keyword('fixed')})"
    assert text == "try n_starts= or init=; fix some (fixed=)"
    assert as_options(text, fit_opts) == "try --starts or --init; fix some (--fixed)"
    neg = f"pass {keyword('negative', 'clip', 'drop')} to export"
    assert (
        as_options(neg, option_map(_subparser("export")))
        == "pass --negative clip or drop to export"
    )
    # names the command has no option for, and other '=' text, stay as they are
    assert as_options("k_dd=1, rho=0.5, n_starts=", {}) == "k_dd=1, rho=0.5, n_starts="
    assert as_options("alpha=0.3 seed=0", fit_opts) == "alpha=0.3 seed=0"


def _negative_table(tmp_path):
    from gonio.io.samples_table import write_samples
    from gonio.samples import BRDFSamples

    rng = np.random.default_rng(0)
    n = 200
    ti = np.repeat(np.radians([20.0, 40.0]), n // 2)
    s = BRDFSamples(
        ti, np.full(n, np.radians(30.0)), rng.uniform(0, 1.2, n), rng.uniform(0, 6, n),
        rng.normal(0.1, 0.2, n), np.full(n, 0.01),
    )  # fmt: skip
    path = tmp_path / "neg.csv"
    write_samples(s, path)
    return s, path


def test_export_refusal_speaks_options_on_the_cli_and_keywords_in_python(tmp_path, capsys):
    from gonio.io import pabopto

    s, path = _negative_table(tmp_path)
    with pytest.raises(ValueError, match=r"pass negative='clip' or 'drop'"):
        pabopto.pabopto_files(s)
    assert main(["export", "pabopto", str(path), str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "pass --negative clip or drop to export" in err
    assert "negative='clip'" not in err


def test_fit_notes_speak_options_on_the_cli(tmp_path, capsys):
    from gonio import brdf
    from gonio.io.samples_table import write_samples
    from gonio.samples import BRDFSamples

    # a Lambertian table fitted by 'lambert + oren_nayar': two diffuse terms, not identifiable
    rng = np.random.default_rng(1)
    n = 400
    ti, to = rng.uniform(0, 1.2, n), rng.uniform(0, 1.2, n)
    pi, po = np.zeros(n), rng.uniform(0, 6, n)
    m = brdf.create("lambert", rho=0.5)
    from gonio.geometry import to_vector

    y = np.asarray(m(to_vector(ti, pi), to_vector(to, po)), float)
    path = tmp_path / "lam.csv"
    write_samples(BRDFSamples(ti, pi, to, po, y, np.full(n, 0.001)), path)
    main(["fit", str(path), "--model", "lambert + lambert"])
    out = capsys.readouterr().out
    assert "not identifiable" in out
    assert "fix some (--fixed)" in out and "fixed=" not in out

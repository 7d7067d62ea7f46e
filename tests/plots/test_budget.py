"""The uncertainty-budget figure (plots/budget.py)."""

from __future__ import annotations

import math

import pytest

from gonio.plots.budget import budget_rows, plot_budget

BUDGET = {
    "k": 2.0,
    "params": {"rho_d": 0.1, "alpha_x": 0.05},
    "statistical": {"rho_d": 1e-4, "alpha_x": 2e-6},
    "terms": {
        "standard_certificate[0]": {"u": 0.002, "unit": "1", "kind": "systematic",
                                    "corrected": True, "contribution":
                                    {"rho_d": 3e-4, "alpha_x": 1e-6}},
        "standard_certificate[1]": {"u": 0.002, "unit": "1", "kind": "systematic",
                                    "corrected": True, "contribution":
                                    {"rho_d": 4e-4, "alpha_x": 0.0}},
        "blur": {"u": 1e-6, "unit": "rad²", "kind": "systematic", "corrected": False,
                 "contribution": {"rho_d": 1e-5, "alpha_x": 5e-5}},
    },
    "combined": {"rho_d": 5.1e-4, "alpha_x": 5.0e-5},
    "expanded": {"rho_d": 1.02e-3, "alpha_x": 1.0e-4},
}  # fmt: skip


def test_rows_combine_components_in_quadrature():
    rows = {name: (vals, corr) for name, vals, corr in budget_rows(BUDGET)}
    assert list(rows) == ["statistical", "standard_certificate", "blur"]
    assert rows["standard_certificate"][0]["rho_d"] == pytest.approx(math.hypot(3e-4, 4e-4) / 0.1)
    assert rows["blur"][1] is False and rows["statistical"][0]["alpha_x"] == pytest.approx(4e-5)


def test_plot_writes_a_png(tmp_path):
    p = plot_budget(BUDGET, tmp_path / "plots" / "budget.png", title="brass")
    data = p.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000
    with pytest.raises(ValueError, match="no fitted parameter"):
        plot_budget({**BUDGET, "params": {}}, tmp_path / "x.png")


def test_cheap_ticks_draw_the_same_figure(tmp_path, monkeypatch):
    """The major ticks made only in view and the minor ticks drawn as one line of marks
    give the pixels of matplotlib's own ticks."""
    import matplotlib.image as mpimg
    import numpy as np

    from gonio.plots import budget as pb

    fast = mpimg.imread(plot_budget(BUDGET, tmp_path / "fast.png", title="brass"))
    monkeypatch.setattr(pb, "_in_view", lambda: lambda base: base)
    monkeypatch.setattr(pb, "_minor_marks", lambda ax: None)
    plain = mpimg.imread(plot_budget(BUDGET, tmp_path / "plain.png", title="brass"))
    assert fast.shape == plain.shape and np.array_equal(fast, plain)

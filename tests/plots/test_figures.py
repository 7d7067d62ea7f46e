import numpy as np
import pytest

from gonio import materials, plots
from gonio.geometry import to_vector
from gonio.samples import BRDFSamples


def _table(n_per=400, seed=0):
    """Samples of rolled brass at a few (θi, φi), in runs as a campaign writes them."""
    rng = np.random.default_rng(seed)
    m = materials.get("rolled_brass")
    parts = []
    for ti in np.radians([0.0, 30.0, 60.0]):
        for pi in (0.0, np.pi / 2):
            to = np.arccos(rng.random(n_per))
            po = rng.uniform(-np.pi, np.pi, n_per)
            wi = to_vector(np.full(n_per, ti), np.full(n_per, pi))
            wo = to_vector(to, po)
            f = m(wi, wo)
            parts.append(BRDFSamples.from_directions(wi, wo, f, 0.01 * f))
    return BRDFSamples.concatenate(parts)


def test_hemisphere_keys_are_the_distinct_incidences():
    s = _table()
    keys = plots.hemisphere_keys(s)
    # at normal incidence φi is undefined (stored 0): 5 distinct (θi, φi), as np.unique says
    ref = np.unique(np.round(np.stack([s.phi_i, s.theta_i], 1), 9), axis=0)[:, ::-1]
    np.testing.assert_array_equal(keys, ref)
    assert len(keys) == 5
    assert len(plots.hemisphere_keys(s, max_panels=3)) == 3
    # rows out of order give the same keys as np.unique over all rows
    perm = s.subset(np.random.default_rng(1).permutation(len(s)))
    np.testing.assert_array_equal(plots.hemisphere_keys(perm), keys)


@pytest.mark.parametrize("bins", [7, 24, 36])
def test_hemisphere_map_matches_histogram2d(bins):
    """The bincount map equals the mean log10 BRDF per cell computed by numpy.histogram2d."""
    s = _table()
    ti, pi = np.radians(30.0), np.pi / 2
    img = plots.hemisphere_map(s, ti, pi, bins)
    sel = np.isclose(s.theta_i, ti) & np.isclose(s.phi_i, pi) & (s.value > 0)
    r = np.degrees(s.theta_o[sel])
    x, y = r * np.cos(s.phi_o[sel]), r * np.sin(s.phi_o[sel])
    edges = np.linspace(-90.0, 90.0, bins + 1)
    tot, _, _ = np.histogram2d(y, x, bins=(edges, edges), weights=np.log10(s.value[sel]))
    cnt, _, _ = np.histogram2d(y, x, bins=(edges, edges))
    ref = np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan)
    np.testing.assert_allclose(img, ref, rtol=1e-12, equal_nan=True)
    assert np.isfinite(img).sum() == (cnt > 0).sum()


def test_incidence_plane_mask_and_sign():
    wi = to_vector(np.full(4, 0.5), np.zeros(4))
    # in the plane (specular side, source side), 1 degree off it, 10 degrees off it
    wo = to_vector(np.full(4, 1.0), np.radians([180.0, 0.0, 181.0, 190.0]))
    s = BRDFSamples.from_directions(wi, wo, np.ones(4), np.full(4, 0.1))
    mask = plots.incidence_plane_mask(s, np.radians(2.0))
    assert mask.tolist() == [True, True, True, False]
    assert plots.incidence_plane_mask(s, np.radians(0.5)).tolist() == [True, True, False, False]
    np.testing.assert_allclose(plots.figures._signed_theta_o(s)[:2], [1.0, -1.0])


def test_pick_angles_spreads_over_the_range():
    assert plots.pick_angles(np.array([3.0, 1.0, 2.0, 1.0])) == [1.0, 2.0, 3.0]
    got = plots.pick_angles(np.arange(21.0), 6)
    assert got[0] == 0.0 and got[-1] == 20.0 and len(got) == 6


def test_plots_write_pngs(tmp_path):
    import cv2

    s = _table(150)
    m = materials.get("rolled_brass")
    paths = [
        plots.plot_hemisphere(s, tmp_path / "h.png", title="t"),
        plots.plot_incidence_plane(s, m, tmp_path / "i.png"),
        plots.plot_residuals(s, m, tmp_path / "r.png"),
    ]
    for p in paths:
        img = cv2.imread(str(p))
        assert img is not None and img.shape[0] > 200 and img.shape[1] > 300
        assert img.std() > 10  # something was drawn
    assert sorted(x.name for x in tmp_path.iterdir()) == ["h.png", "i.png", "r.png"]
    with pytest.raises(ValueError, match="empty"):
        plots.plot_hemisphere(s.subset(np.array([], dtype=int)), tmp_path / "e.png")


def test_decade_labels_without_mathtext():
    assert plots.decade_label(100.0) == "10²"
    assert plots.decade_label(1e-3) == "10⁻³"
    assert plots.decade_label(1.0) == "10⁰"
    assert plots.decade_label(2e-3) == "0.002"
    assert plots.decade_label(0.0) == "" and plots.decade_label(float("nan")) == ""


# -- publication figures (issue 32) ------------------------------------------------------------
def _texts(fig) -> str:
    out = [t.get_text() for t in fig.texts]
    for ax in fig.axes:
        out += [ax.get_title(), ax.get_xlabel(), ax.get_ylabel()]
        out += [t.get_text() for t in ax.texts]
        leg = ax.get_legend()
        out += [t.get_text() for t in leg.get_texts()] if leg else []
    for leg in fig.legends:
        out += [t.get_text() for t in leg.get_texts()]
    return "\n".join(out)


@pytest.fixture
def drawn(monkeypatch):
    """The figures the plot functions make, instead of their PNGs."""
    from gonio.plots import figures

    figs = []
    monkeypatch.setattr(figures, "_save", lambda fig, path: figs.append(fig) or path)
    return figs


def test_log_axis_reads_whatever_its_range():
    from gonio.plots.figures import _figure

    for lo, hi, want in ((0.14, 0.52, {"0.2", "0.3", "0.4", "0.5"}), (0.02, 0.09, {"0.02"}),
                         (1e-3, 10.0, {"10⁻³", "10⁰", "10¹"})):  # fmt: skip
        fig = _figure(3.5, 2.5)
        ax = fig.add_subplot()
        ax.plot([0, 1], [lo, hi])
        plots.log_axis(ax)
        ax.set_ylim(lo, hi)
        fig.canvas.draw()
        labels = {t.get_text() for t in ax.get_yticklabels(minor=True) + ax.get_yticklabels()}
        labels.discard("")
        assert want <= labels, (lo, hi, labels)
        assert len(labels) >= 3


def test_figures_at_150_dpi_or_the_chosen(tmp_path, monkeypatch):
    import cv2

    s = _table(100).subset(np.flatnonzero(_table(100).phi_i == 0))
    m = materials.get("rolled_brass")
    img = cv2.imread(str(plots.plot_incidence_plane(s, m, tmp_path / "a.png")))
    assert img.shape[1] == round(3.5 * 150)  # one panel: a single-column figure
    monkeypatch.setenv("GONIO_PLOT_DPI", "300")
    img = cv2.imread(str(plots.plot_incidence_plane(s, m, tmp_path / "b.png")))
    assert img.shape[1] == round(3.5 * 300)
    monkeypatch.setenv("GONIO_PLOT_DPI", "30")
    with pytest.raises(ValueError, match="outside"):
        plots.plot_incidence_plane(s, m, tmp_path / "c.png")


def test_figures_say_what_they_show(drawn, tmp_path):
    s = _table(3000)
    m = materials.get("rolled_brass")
    plots.plot_residuals(s, m, tmp_path / "r.png", max_points=500)
    text = _texts(drawn[-1])
    assert "500 of 18,000 points shown" in text
    assert "f: fitted model, y: measured BRDF, σ" in text and "end bins also hold" in text
    plots.plot_hemisphere(s, tmp_path / "h.png", max_panels=4)
    text = _texts(drawn[-1])
    assert "4 of 5 incidences shown" in text  # (θi 0° has one azimuth)
    assert {"source direction", "specular direction", "no sample"} <= set(text.splitlines())
    plots.plot_incidence_plane(s, m, tmp_path / "i.png", max_points=20)
    text = _texts(drawn[-1])
    assert "fitted model" in text and "158 samples within 0.5° of the plane, 99 shown" in text
    assert {"θi = 0°", "θi = 30°", "θi = 60°"} <= set(text.splitlines())  # every panel's θi


def test_outliers_do_not_set_the_residual_axis(drawn, tmp_path):
    s = _table(200)
    v = s.value.copy()
    v[:2] *= 100.0  # two samples far off: 100 σ
    s = BRDFSamples(s.theta_i, s.phi_i, s.theta_o, s.phi_o, v, s.sigma)
    plots.plot_residuals(s, materials.get("rolled_brass"), tmp_path / "r.png")
    lo, hi = drawn[-1].axes[0].get_ylim()
    assert hi <= 5.0 and lo >= -5.0
    assert "2 beyond the axis" in _texts(drawn[-1])


def test_empty_cells_are_outside_the_colour_scale():
    import matplotlib as mpl

    from gonio.plots.figures import EMPTY

    magma = mpl.colormaps["magma"](np.linspace(0, 1, 256))[:, :3]
    gap = np.abs(magma - np.array(mpl.colors.to_rgb(EMPTY))).sum(axis=1).min()
    assert gap > 0.3

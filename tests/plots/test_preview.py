"""``plots/preview.png``: the truth and the fit rendered by Radiance (rtrace through
pyradiance's binaries), checked against an independent numpy evaluation of the same scene."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from gonio import brdf, materials
from gonio.io.radiance import model_material
from gonio.plots import preview


def _tools():
    pytest.importorskip("pyradiance")


#: The default campaign's fit of rolled brass (``gonio campaign``, seed 0: its fit.json)
BRASS_FIT = dict(rho_d=0.10000161877075074, rho_s=0.32960038478660425,
                 alpha_x=0.05004737319487681, alpha_y=0.16010565557983925)  # fmt: skip
#: ``gonio campaign --model lambert`` on rolled brass (seed 0: its fit.json)
BRASS_LAMBERT = dict(rho=0.2545)


def _numpy_render(model, size: int) -> tuple[np.ndarray, np.ndarray]:
    """The same scene evaluated in numpy: each light's irradiance × cos × the BRDF at its
    centre direction, in the frame the ``BRTDfunc`` builds (x: ``u`` = +x projected into the
    surface, z: the normal), for every pixel whose ray meets the sphere."""
    o, d, hit = preview._camera(size)
    o, d = o[hit.ravel()], d[hit.ravel()]
    b = np.einsum("ij,ij->i", o, d)
    t = -b - np.sqrt(b * b - (o * o).sum(axis=1) + 1.0)
    n = o + t[:, None] * d  # the unit sphere: the point is its normal
    tx = np.array([1.0, 0.0, 0.0]) - n[:, :1] * n
    tx /= np.linalg.norm(tx, axis=1, keepdims=True)
    ty = np.cross(n, tx)

    def local(v):
        return np.stack([(v * tx).sum(1), (v * ty).sum(1), (v * n).sum(1)], axis=1)

    wo = local(-d)
    lights = [(preview.KEY_DIRECTION, preview.KEY_IRRADIANCE)]
    lights += [(e, preview.ENVIRONMENT_IRRADIANCE) for e in preview.ENVIRONMENT]
    out = np.zeros(len(d))
    for v, e in lights:
        v = np.asarray(v, dtype=np.float64) / np.linalg.norm(v)
        wi = local(np.broadcast_to(v, d.shape))
        lit = wi[:, 2] > 0.0
        out[lit] += e * wi[lit, 2] * model(wi[lit], wo[lit])
    img = np.zeros(hit.shape)
    img[hit] = out
    return img, hit


@pytest.mark.parametrize(
    ("model", "cls"),
    [
        (materials.get("rolled_brass"), "metal"),  # Ward eq. 5a: BRTDfunc
        (brdf.create("ward_gmd", **BRASS_FIT), "metal"),  # metal2
        (materials.get("white_sand"), "diffuse"),  # Oren-Nayar eq. 27-29: BRTDfunc
        (materials.get("blue_paint_lafortune"), "dielectric"),  # Lafortune: BRTDfunc
    ],
)
def test_the_render_is_the_scene_evaluated_independently(model, cls):
    """rtrace's sphere equals the numpy evaluation of the same lights and BRDF on every
    pixel (measured worst: 2.9e-5 Ward, 9.5e-6 metal2, 2.4e-5 Lafortune, 2.5e-7 Oren-Nayar;
    3e-5 is the bound of the rendered BRDF in tests/io/test_radiance.py: Radiance's
    single-precision colours)."""
    _tools()
    got, mask = preview.render_sphere(model_material(model, cls, name="m"), 64)
    want, hit = _numpy_render(model, 64)
    assert np.array_equal(mask, hit) and mask.sum() > 0.5 * mask.size
    np.testing.assert_allclose(got[mask], want[mask], rtol=3e-5, atol=0.0)
    assert np.all(got[~mask] == 0.0) and np.all(want[mask] > 0.0)


def test_preview_of_a_good_fit_is_close_and_of_a_wrong_model_far(tmp_path):
    """The default campaign's Ward fit of rolled brass: mean |Δ| 0.021 % over the sphere
    (measured); a Lambert fit of the same brass: 141 % (the highlights missing, the rest
    about 2.5 times too bright)."""
    _tools()
    truth = materials.get("rolled_brass")
    good = preview.plot_preview(truth, brdf.create("ward", **BRASS_FIT), tmp_path / "good.png",
                                "rolled_brass (ward)", "metal")  # fmt: skip
    bad = preview.plot_preview(truth, brdf.create("lambert", **BRASS_LAMBERT),
                               tmp_path / "bad.png", "rolled_brass (lambert)", "metal")  # fmt: skip
    assert (tmp_path / "good.png").stat().st_size > 10_000 and (tmp_path / "bad.png").is_file()
    assert good["notes"] == [] and good["n_pixels"] > 0.9 * good["mask"].sum()
    assert good["mean_abs_rel_diff"] < 1e-3 and good["p95_abs_rel_diff"] < 5e-3
    assert bad["mean_abs_rel_diff"] > 1.0
    same = preview.plot_preview(truth, truth, tmp_path / "same.png", "", "metal", size=32)
    assert same["mean_abs_rel_diff"] == 0.0  # the same material: the same pixels


def test_a_model_without_a_radiance_form_draws_its_half_as_a_note(tmp_path):
    _tools()
    truth = materials.get("garnet_red_paint")  # spectral li_torrance: no Radiance form
    fit = brdf.create("lambert", rho=0.3)
    notes = preview.preview_notes(truth, fit, "dielectric")
    assert len(notes) == 1 and notes[0].startswith("plots/preview.png: truth not rendered:")
    out = preview.plot_preview(truth, fit, tmp_path / "p.png", "", "dielectric", size=32)
    assert (tmp_path / "p.png").is_file() and out["mean_abs_rel_diff"] is None
    assert out["notes"] == [notes[0].removeprefix("plots/preview.png: ")]
    assert preview.preview_notes(fit, fit) == []


def test_without_pyradiance_the_preview_is_skipped_with_a_note(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyradiance", None)  # import pyradiance fails
    monkeypatch.setenv("PATH", "")
    why = preview.unavailable()
    assert why is not None and "pip install 'gonio[radiance]'" in why
    truth = materials.get("rolled_brass")
    assert preview.preview_notes(truth, truth, "metal") == [why]


def test_a_renderer_failure_costs_the_preview_only(tmp_path, monkeypatch, capsys):
    """A Radiance program that fails inside the plot job must not fail the campaign after
    its measurement: the preview is left out and the reason printed."""
    import subprocess

    import gonio.plots.preview as pv
    from gonio import materials
    from gonio.campaign import Plan
    from gonio.campaign.report import draw_preview

    def broken(*a, **k):
        raise subprocess.CalledProcessError(1, ["rtrace"], stderr="rtrace: fatal")

    monkeypatch.setattr(pv, "plot_preview", broken)
    truth = materials.get("rolled_brass")

    from types import SimpleNamespace

    result = SimpleNamespace(model=truth, params=dict(truth.params))
    draw_preview("preview", truth, result, Plan(), {"class": "metal"}, tmp_path, "t")
    assert not (tmp_path / "preview.png").exists()
    assert "plots/preview.png not drawn: CalledProcessError" in capsys.readouterr().err

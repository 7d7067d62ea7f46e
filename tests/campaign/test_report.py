"""The campaign summary's truth: every fitted parameter that has a true value has it."""

from __future__ import annotations

from gonio import materials
from gonio.brdf.lafortune import Lafortune
from gonio.campaign.report import _lobe_truth


def test_lafortune_lobes_are_matched_to_the_truth_by_their_exponent():
    """Issue 35: the summary's truth held only rho_d and r_m of a Lafortune material, so
    the lobes' fitted parameters were never compared with anything (the coverage matrix
    counted one parameter of thirteen). The fitted lobes come in any order; each is matched
    to the true lobe of the same rank of n."""
    truth = materials.get("blue_paint_lafortune")
    lobes = list(truth.params["lobes"])
    fitted = Lafortune(lobes=[lobes[2], lobes[0], lobes[1]], rho_d=0.12)  # another order
    got = _lobe_truth(truth, fitted)
    assert len(got) == 12
    for i, lobe in enumerate([lobes[2], lobes[0], lobes[1]]):
        assert [got[f"lobes[{i}].{k}"] for k in ("c_x", "c_y", "c_z", "n")] == [
            float(x) for x in lobe[:4]
        ]
    assert _lobe_truth(truth, Lafortune(lobes=lobes[:2], rho_d=0.1)) == {}
    assert _lobe_truth(materials.get("rolled_brass"), fitted) == {}

"""What a campaign keeps of its raw frames (issue 32): compressed frames read back bit for
bit, and a resumed campaign uses them as it used the uncompressed ones."""

import numpy as np
import pytest

from gonio.campaign import Plan, run
from gonio.campaign.raw import disk_usage, keep_raw
from gonio.io.images import read_image, sidecar_path

PLAN = Plan(material="rolled_brass", theta_i_deg=(30.0,), rotations_deg=(0.0,), plots=False,
            preset="ideal")  # fmt: skip


def test_compressed_raw_frames_read_back_bit_identically_and_resume(tmp_path):
    out = tmp_path / "c"
    first = run(PLAN, out, workers=1)
    frames = sorted((out / "raw").rglob("*.tif"))
    assert frames
    before = {p: (read_image(p)[0], sidecar_path(p).read_bytes()) for p in frames}
    size = disk_usage(out)
    keep_raw(out, "compressed")
    after = disk_usage(out)
    assert after["raw"] < 0.7 * size["raw"] and after["total"] - after["raw"] == (
        size["total"] - size["raw"]
    )
    for p, (img, car) in before.items():
        back, _ = read_image(p)
        assert back.dtype == img.dtype and np.array_equal(back, img)
        assert sidecar_path(p).read_bytes() == car
    again = run(PLAN, out, resume=True, workers=1)  # the compressed frames, not new captures
    assert again.summary["n_captures"]["resumed_groups"] == 2  # (sample; standard + background)
    assert again.summary["fit"] == first.summary["fit"]
    assert np.array_equal(again.samples.value, first.samples.value)
    keep_raw(out, "none")
    assert not (out / "raw").exists() and disk_usage(out)["raw"] == 0
    with pytest.raises(ValueError, match="expected one of keep, compressed, none"):
        keep_raw(out, "zip")

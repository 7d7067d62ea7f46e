"""The posed sample (gonio.simulator.lbl_pose): one instrument's pose never leaks into another's."""

import numpy as np
from gonio.simulator import LBLInstrument


def _image(seed: int) -> np.ndarray:
    inst = LBLInstrument(width=160, height=120, effects={"sample_tilt": 0.01}, instrument_seed=seed)
    return inst.capture("rolled_brass", 0.5, 0.0, noise=False)[0]


def test_a_tilted_sample_is_posed_by_its_own_instrument_not_the_first_one_with_the_same_optics():
    # both instruments share the traced geometry (same optics); the tilt's azimuth comes from
    # the instrument seed, so the second image must not depend on the first capture
    alone = _image(2)
    _image(1)  # another instrument, same optics, another tilt azimuth
    after = _image(2)
    other = _image(1)
    assert np.array_equal(alone, after)
    assert not np.array_equal(alone, other)  # the seeds' tilts really differ

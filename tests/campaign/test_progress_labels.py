"""A campaign's first seconds are labelled on a terminal (issue 32): the warm-up and the
calibration show their own bar before the captures'."""

import io

import pytest

from gonio.campaign import Plan, run


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.mark.slow
def test_warm_up_and_calibration_are_labelled_on_a_terminal():
    out = _Terminal()
    plan = Plan(material="rolled_brass", theta_i_deg=(30.0,), rotations_deg=(0.0,), plots=False)
    run(plan, None, quiet=False, stream=out, workers=1)
    text = out.getvalue()
    assert "warm-up + calibration [" in text
    assert text.index("warm-up + calibration") < text.index("fit ward")
    quiet = _Terminal()
    run(plan, None, quiet=True, stream=quiet, workers=1)
    assert quiet.getvalue() == ""

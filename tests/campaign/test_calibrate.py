"""The simulated instrument's calibration captures and the laboratory's calibration."""

from __future__ import annotations

import numpy as np
from gonio.simulator import LBLInstrument
from gonio.simulator.effects import realise

from gonio.campaign import calibrate
from gonio.campaign.executor import CampaignExecutor


def _same_frames(a, b):
    return len(a) == len(b) and all(
        np.array_equal(x[-2], y[-2]) and x[-1] == y[-1] for x, y in zip(a, b)
    )


def test_calibration_jobs_in_parallel_give_the_serial_calibration():
    # the captures' seeds are drawn before the jobs run, so the captures and the calibration
    # made from them are the same bit for bit whether the jobs run here or on two processes
    inst = LBLInstrument(effects=realise("modern", 2), instrument_seed=2)
    nominal = inst.mirror.to_dict()
    import cv2
    import scipy.optimize  # noqa: F401
    from threadpoolctl import threadpool_limits

    calibrate._CACHE.clear()
    # every BLAS loaded (OpenCV loads its own OpenBLAS at its first decomposition) and on one
    # thread in both runs: the lens calibration's last bits depend on OpenCV's BLAS thread
    # count (0.21830652120713856 px rms with two threads, 0.21830652120714 with one)
    cv2.SVDecomp(np.eye(8))
    with threadpool_limits(limits=1):
        serial = calibrate.take_captures(inst, seed=4)
        cal_serial = calibrate.calibrate(serial, nominal)
        calibrate._CACHE.clear()
        with CampaignExecutor(2) as ex:
            par = calibrate.take_captures(inst, seed=4, parallel=ex.parallel)
            cal_par = calibrate.calibrate(par, nominal, parallel=ex.parallel)
    assert all(np.array_equal(a, b) for a, b in zip(serial["board"], par["board"]))
    assert _same_frames(serial["mirror"], par["mirror"])
    assert all(_same_frames(a, b) for a, b in zip(serial["ladder"], par["ladder"]))
    assert len(par["ladder"]) == calibrate.LADDER_REPEATS
    assert cal_par.lens == cal_serial.lens
    assert 2e-4 <= cal_par.lens["fx_u_rel"] < 0.05
    assert cal_par.mirror.to_dict() == cal_serial.mirror.to_dict()
    assert cal_par.fstops.to_dict() == cal_serial.fstops.to_dict()
    assert cal_par.info == cal_serial.info


def test_the_pipelined_laboratory_calibration_is_calibrate_of_take_captures():
    # laboratory_calibration runs each kind of capture and its analysis in one job (views ->
    # lens, spots -> centroids, ladder -> f-stops): the same draws, so the same calibration
    inst = LBLInstrument(effects=realise("modern", 3), instrument_seed=3)
    nominal = inst.mirror.to_dict()
    import cv2
    from threadpoolctl import threadpool_limits

    cv2.SVDecomp(np.eye(8))  # OpenCV's BLAS loaded, on one thread below (see the test above)
    design = {"sample_radius": float(inst.sample_radius),
              "spot_radius": float(inst.source.spot_radius)}  # fmt: skip
    with threadpool_limits(limits=1):
        calibrate._CACHE.clear()
        two_sided = calibrate.calibrate(calibrate.take_captures(inst, seed=5), nominal,
                                        design=design)  # fmt: skip
        calibrate._CACHE.clear()
        warmed = []
        with CampaignExecutor(2) as ex:  # the lens's job begun before the warm-up
            piped = calibrate.laboratory_calibration(
                inst, nominal, seed=5, parallel=ex.parallel, start=ex.start,
                warm=lambda: warmed.append(len(calibrate._CACHE)),
            )  # fmt: skip
        again = calibrate.laboratory_calibration(inst, nominal, seed=5, warm=warmed.append)
    assert warmed == [0]  # once, before the captures; not for the kept calibration
    assert again.lens == piped.lens
    assert piped.lens == two_sided.lens
    assert piped.mirror.to_dict() == two_sided.mirror.to_dict()
    assert piped.fstops.to_dict() == two_sided.fstops.to_dict()
    assert piped.sensor == two_sided.sensor
    assert {k: v for k, v in piped.info.items() if k != "instrument"} == two_sided.info

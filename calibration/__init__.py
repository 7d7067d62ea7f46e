"""From raw captures to BRDF samples.

Eq. 2 radiometry (:mod:`.radiometry`), exposure merging (:mod:`.merge`), fisheye lens
calibration with ChArUco (:mod:`.lens`), angle recovery by eq. 3 or exact tracing
(:mod:`.angles`), data thinning (:mod:`.thinning`) and the reduction pipeline
(:mod:`.reduce`). References: Ward 1992 §3.2, eq. 2 and eq. 3.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078
   §3.2: calibration and data reduction, eq. 2 and eq. 3.
"""

from gonio.calibration.angles import MirrorGeometry, reflection_directions, trace
from gonio.calibration.merge import calibrate_response, merge_debevec, merge_linear
from gonio.calibration.radiometry import Measurement, Reflectance, SensorModel, eq2, linearize
from gonio.calibration.reduce import (
    Capture,
    ReductionResult,
    load_capture,
    load_lens,
    reduce_capture,
    reduce_many,
    reduce_selected,
)
from gonio.calibration.thinning import ThinningResult, thin

__all__ = [
    "Capture",
    "Measurement",
    "MirrorGeometry",
    "ReductionResult",
    "Reflectance",
    "SensorModel",
    "ThinningResult",
    "calibrate_response",
    "eq2",
    "linearize",
    "load_capture",
    "load_lens",
    "merge_debevec",
    "merge_linear",
    "reduce_capture",
    "reduce_many",
    "reduce_selected",
    "reflection_directions",
    "thin",
    "trace",
]

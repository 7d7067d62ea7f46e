"""gonio — a virtual gonioreflectometer.

Simulates the LBL imaging gonioreflectometer (Ward 1992) and the Cornell three-axis
gonioreflectometer (Li & Torrance 2005): raw captures from any BRDF, calibration and data
reduction back to BRDF samples, and model fitting. See ``README.md`` and ``docs/architecture.md``.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078
   §3: the LBL imaging gonioreflectometer, its calibration and data reduction.
.. [LiTorrance2005] H. Li and K. E. Torrance, "A practical, comprehensive light reflection model",
   Technical report, Program of Computer Graphics, Cornell University, 2005.
   §5.1: the Cornell automated three-axis gonioreflectometer.
"""

__version__ = "0.1.0"

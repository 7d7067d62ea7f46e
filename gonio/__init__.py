"""gonio — a virtual gonioreflectometer.

Simulates the LBL imaging gonioreflectometer (Ward 1992) and the Cornell three-axis
gonioreflectometer (Li & Torrance 2005): raw captures from any BRDF, calibration and data
reduction back to BRDF samples, and model fitting. See ``README.md`` and ``DESIGN.md``.
"""

__version__ = "0.1.0"

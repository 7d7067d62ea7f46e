"""From raw captures to BRDF samples.

Eq. 2 radiometry, exposure merging, lens and mirror calibration, angle recovery, thinning,
spectral reduction.
"""

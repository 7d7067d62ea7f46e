"""Fitting reflectance models to BRDF samples.

:func:`fit` (in :mod:`gonio.fit.core`) fits any registered model or sum of models by bounded
non-linear least squares; the linear coefficients of a model are solved exactly for each trial
of its other parameters by :mod:`gonio.fit.linear` (variable projection).
"""

from gonio.fit.core import *  # noqa: F403  (the public names, listed in core.__all__)
from gonio.fit.core import __all__  # noqa: F401

"""Campaigns: a measurement plan run through an instrument, reduced, fitted and reported.

The rooms inside (``docs/architecture.md``):

* :mod:`gonio.campaign.lbl` — the LBL imaging gonioreflectometer's campaign (Ward 1992 §4):
  :func:`run` and its :class:`Plan`;
* :mod:`gonio.campaign.cornell` — the Cornell three-axis instrument's campaign (Li and
  Torrance 2005 §5.1);
* :mod:`gonio.campaign.drivers` — both campaigns through the real drivers and the fake devices;
* :mod:`gonio.campaign.sweep` — grids of campaigns on a process pool or a Dask cluster;
* :mod:`gonio.campaign.design`, :mod:`gonio.campaign.design_lbl`,
  :mod:`gonio.campaign.design_adaptive` — the plan that reaches target uncertainties in the
  least instrument time (``gonio design``, ``gonio campaign --adaptive``);
* :mod:`gonio.campaign.executor` — the one place for concurrency: the worker pool, the plot
  process, the I/O thread and the BLAS thread limit that all campaigns share.

``gonio.campaign.run`` and ``gonio.campaign.Plan`` are the LBL campaign's (the default
instrument).
"""

from gonio.campaign.lbl import *  # noqa: F403  (the public names, listed in lbl.__all__)
from gonio.campaign.lbl import __all__  # noqa: F401

"""Figures of BRDF samples and fitted models (matplotlib, drawn off-screen).

The campaign figures live in :mod:`gonio.plots.figures`; a campaign draws them in a separate
process (:mod:`gonio.campaign.plot_worker`).
"""

from gonio.plots.figures import (
    decade_label,
    hemisphere_keys,
    hemisphere_map,
    incidence_plane_mask,
    log_axis,
    pick_angles,
    plot_hemisphere,
    plot_incidence_plane,
    plot_residuals,
)

__all__ = [
    "decade_label",
    "hemisphere_keys",
    "hemisphere_map",
    "incidence_plane_mask",
    "log_axis",
    "pick_angles",
    "plot_hemisphere",
    "plot_incidence_plane",
    "plot_residuals",
]

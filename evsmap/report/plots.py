"""The report's figures (matplotlib, drawn off-screen through the Agg canvas), one module per
family: :mod:`~evsmap.report.network_plots`, :mod:`~evsmap.report.mapping_plots`,
:mod:`~evsmap.report.map_views` (their shared parts in :mod:`~evsmap.report.figure_base`).

* :func:`networks_plot` - measured FPS against FLOPs for the networks of Tables I and II, and
  each network's speed over ESANet-R34's beside the paper's ratio.
* :func:`mapping_plot` - map update rate, segmentation + update rate and map size per sequence
  and system.
* :func:`qualitative_plot` - segmentation overlays beside the ground truth, and a top-down
  render of each system's semantic map.

Each returns ``False`` (and writes nothing) when it has no data to draw.
"""

from evsmap.report.figure_base import MAP_ROWS
from evsmap.report.map_views import qualitative_plot, split_map_name, top_down
from evsmap.report.mapping_plots import (
    GROWTH_READINGS,
    MAPPING_QUANTITIES,
    growth_plot,
    mapping_entries,
    mapping_plot,
)
from evsmap.report.network_plots import (
    SPEED_BASELINE,
    network_points,
    networks_plot,
    place_labels,
    speed_ratios,
)

__all__ = ["GROWTH_READINGS", "MAPPING_QUANTITIES", "MAP_ROWS", "SPEED_BASELINE", "growth_plot",
           "mapping_entries", "mapping_plot", "network_points", "networks_plot", "place_labels",
           "qualitative_plot", "speed_ratios", "split_map_name", "top_down"]

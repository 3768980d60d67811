"""Every figure of the package: the one owner of matplotlib (imported on first use, Agg backend), the one
colormap of uncertainty and error maps (:data:`CMAP`) with a colour bar on every value map, and PNGs written
atomically.

* :mod:`~bayes_brdf.plots.base` -- the backend, the colormap, :func:`show_map`, value ranges, :func:`save_figure`;
* :mod:`~bayes_brdf.plots.maps` -- :func:`write_map` (EXR + colour-mapped PNG) and panel grids;
* :mod:`~bayes_brdf.plots.charts` -- lines with their spread, the reliability diagram, std against error;
* :mod:`~bayes_brdf.plots.views` -- candidate views by score, the views of guided capture by round;
* :mod:`~bayes_brdf.plots.paper` -- the layouts of Figs. 4-6 of the experiments;
* :mod:`~bayes_brdf.plots.decoder` -- the latent decoder's training curve and samples.

Functions here draw what they are given (tensors or arrays); the numbers come from
:mod:`bayes_brdf.uncertainty`, the experiments and the CLI. ``render``, ``models`` and ``samplers`` never
import this package.

Example:
    >>> import tempfile, torch
    >>> from pathlib import Path
    >>> png = write_map(Path(tempfile.mkdtemp()) / "std", torch.rand(8, 8), title="std", exr=False)
    >>> png.suffix
    '.png'
"""
from .base import CMAP, MASK_COLOURS, as_hwc, colorize, save_figure, scalar_map, show_map
from .charts import line_plot, reliability, std_vs_error
from .decoder import decoder_curve, decoder_samples
from .maps import map_panel, panel_grid, rgb_panel, write_map
from .paper import fig4_overview, fig5_overview, fig6_overview
from .views import plot_candidates, views_polar

__all__ = ["CMAP", "MASK_COLOURS", "as_hwc", "colorize", "save_figure", "scalar_map", "show_map", "line_plot",
           "reliability", "std_vs_error", "decoder_curve", "decoder_samples", "map_panel", "panel_grid", "rgb_panel",
           "write_map", "fig4_overview", "fig5_overview", "fig6_overview", "plot_candidates", "views_polar"]

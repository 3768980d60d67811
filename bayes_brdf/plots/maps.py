"""Maps as figures: a value map as EXR plus a colour-mapped PNG (:func:`write_map`), and grids of RGB and value
panels where every map carries its range (:func:`panel_grid`).

Value maps use the one colormap (:data:`~bayes_brdf.plots.base.CMAP`) with a colour bar; RGB images (photos,
renders, albedo) say their range (``linear 0-1, shown sRGB``) in the title instead.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ..errors import InputError
from .base import as_hwc, pyplot, robust_max, save_figure, scalar_map, show_map


def write_map(path, value, *, title: str = "", vmin: float = 0.0, vmax: float | None = None,
              unit: str = "", exr: bool = True, masks: dict | None = None) -> Path:
    """Write ``value`` (``[H, W]``, ``[H, W, C]`` or channel-first ``[C, H, W]``) as ``path.exr`` and a
    colour-mapped ``path.png`` with a colour bar (channels are averaged for the PNG). The EXR is RGB: one
    channel is repeated, two are stored as R, G with B = 0. ``masks`` ``{label: [H, W] bool}`` are pixels
    without a value: NaN in the EXR, a flat colour named in the PNG's legend (:func:`~bayes_brdf.plots.base.show_map`).
    Both files are written atomically. Returns the PNG path."""
    from ..io import write_exr

    path = Path(path).with_suffix("")
    path.parent.mkdir(parents=True, exist_ok=True)
    t = as_hwc(value)
    if t.dim() != 2 and not (t.dim() == 3 and t.shape[-1] <= 3):
        raise InputError(f"write_map: a map is [H, W], [H, W, C] or [C, H, W] with C <= 3, got {tuple(t.shape)}",
                         where=path, fix="write one channel group per call")
    if masks:
        left_out = torch.zeros(t.shape[:2], dtype=torch.bool)
        for m in masks.values():
            left_out |= torch.as_tensor(m).detach().cpu().bool()
        t = t.masked_fill(left_out[..., None] if t.dim() == 3 else left_out, float("nan"))
    if exr:
        e = t[..., None] if t.dim() == 2 else t
        if e.shape[-1] == 1:   # grey: the value in R, G and B (every viewer shows it)
            e = e.expand(*e.shape[:2], 3)
        elif e.shape[-1] == 2:   # e.g. normal slopes: R, G with B = 0
            e = torch.cat([e, torch.zeros_like(e[..., :1])], -1)
        write_exr(path.with_suffix(".exr"), e)
    s = scalar_map(t).numpy()
    if vmax is None:
        vmax = robust_max(s)
    vmax = vmax if vmax > vmin else vmin + 1e-12
    legend_rows = sum(bool(torch.as_tensor(m).any()) for m in (masks or {}).values())
    fig, ax = pyplot().subplots(figsize=(3.6, 3.0 + 0.22 * legend_rows), dpi=100)
    show_map(fig, ax, np.ma.masked_invalid(s), vmin, vmax, title, unit, masks=masks)
    fig.tight_layout()
    return save_figure(fig, path.with_suffix(".png"), dpi=100)


def rgb_panel(img, title: str) -> dict:
    """An RGB panel: ``img [H, W, 3]`` (or ``[3, H, W]``) linear in 0-1, shown sRGB."""
    from ..io.images import linear_to_srgb

    rgb = linear_to_srgb(as_hwc(img).clamp(0, 1)).numpy()
    return {"rgb": rgb, "title": f"{title}\n(RGB, linear 0–1, shown sRGB)"}


def map_panel(value, title: str, vmin: float = 0.0, vmax: float | None = None, masks: dict | None = None) -> dict:
    """A value panel (channels averaged) with a colour bar from ``vmin`` to ``vmax`` (``None``: the 99th
    percentile of this map, or the largest of those of all such panels in a :func:`panel_grid` with
    ``share=True``)."""
    return {"map": scalar_map(value).numpy(), "title": title, "vmin": vmin, "vmax": vmax, "masks": masks}


#: the two looks of a panel grid: the report's (read at about 1000 px wide) and the experiments' (compact)
#: -- one panel's size in inches, the room a title takes, the panel titles' font size, padding, dpi
GRID_STYLES = {"report": dict(panel=(3.1, 3.0), title_space=0.4, fontsize=11, w_pad=2.0, dpi=90),
               "compact": dict(panel=(2.6, 2.4), title_space=0.3, fontsize=8, w_pad=None, dpi=110)}


def panel_grid(path, rows: list, *, ncols: int | None = None, title: str = "", share: bool = False,
               style: str = "report", panel_size: tuple[float, float] | None = None) -> Path:
    """Panels (:func:`rgb_panel` / :func:`map_panel`, ``None`` for a gap) as one PNG.

    ``rows`` is a list of rows, or one flat list of panels wrapped every ``ncols`` (default: all in one
    row; ``ncols`` columns even when fewer panels are given). ``share``: the value panels without a
    ``vmax`` share one range (the largest of their 99th percentiles). ``style``: a key of
    :data:`GRID_STYLES`; ``panel_size`` ``(width, height)`` in inches overrides the style's.
    """
    st = GRID_STYLES[style]
    if rows and not isinstance(rows[0], list):   # one flat list of panels
        ncols = ncols or len(rows)
        rows = [rows[i:i + ncols] for i in range(0, len(rows), ncols)]
    shared = max((robust_max(p["map"]) for row in rows for p in row
                  if p is not None and "map" in p and p["vmax"] is None), default=None) if share else None
    w, h = panel_size or st["panel"]
    ncols = max([ncols or 0] + [len(r) for r in rows])
    fs = st["fontsize"]
    height = h * len(rows) + (st["title_space"] if title else 0)
    fig, axes = pyplot().subplots(len(rows), ncols, figsize=(w * ncols, height), squeeze=False)
    for ax in axes.flat:
        ax.set_axis_off()
    for r, row in enumerate(rows):
        for c, p in enumerate(row):
            if p is None:
                continue
            ax = axes[r, c]
            if "rgb" in p:
                ax.imshow(p["rgb"], interpolation="nearest")
                ax.set_title(p["title"], fontsize=fs - 1)
                ax.set_axis_off()
            else:
                vmax = p["vmax"] if p["vmax"] is not None else shared if share else robust_max(p["map"])
                show_map(fig, ax, p["map"], p["vmin"], vmax, p["title"], fontsize=fs, masks=p.get("masks"))
    if title:
        fig.suptitle(title, fontsize=fs + 1)
    fig.tight_layout(w_pad=st["w_pad"])
    return save_figure(fig, path, dpi=st["dpi"])


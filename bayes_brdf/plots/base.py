"""What every figure shares: matplotlib on the Agg backend, the one colormap, value maps with a colour bar,
value ranges, display curves and atomic PNG writing.

Example:
    >>> import numpy as np
    >>> colorize(np.array([[0.0, 0.5, 1.0]]), vmin=0.0, vmax=1.0).shape
    (1, 3, 3)
    >>> robust_max(np.array([np.nan, np.nan]))
    1.0
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import Tensor

#: the one colormap of every uncertainty / error figure
CMAP = "inferno"
#: colours of pixels a map leaves out (never a colour of :data:`CMAP`): see ``masks`` of :func:`show_map`
MASK_COLOURS = ("#22c3e6", "#8a8a8a", "#3ddc84")


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (figures go to files, never to a window): the one place the
    package imports it, on first use, so that ``import bayes_brdf`` and the CLI's ``--help`` stay fast."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def save_figure(fig, path, *, dpi: int = 110, tight: bool = False) -> Path:
    """Write ``fig`` to ``path`` (PNG; folders created) atomically and close it (``tight``: cropped to its content)."""
    from ..io.outputs import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, **({"bbox_inches": "tight"} if tight else {}))
    pyplot().close(fig)
    return Path(path)


def as_numpy(x) -> np.ndarray:
    """``x`` (a tensor or an array) as a float32 numpy array on the CPU."""
    return np.asarray(torch.as_tensor(x).detach().float().cpu())


def as_hwc(img) -> Tensor:
    """``img`` as a CPU float ``[H, W]`` or ``[H, W, C]`` (a channel-first ``[C, H, W]`` map with C <= 3 is moved)."""
    t = torch.as_tensor(img).detach().float().cpu()
    if t.dim() == 3 and t.shape[0] in (1, 2, 3) and t.shape[-1] not in (1, 2, 3):
        t = t.movedim(0, -1)  # channel-first map
    return t


def scalar_map(img) -> Tensor:
    """``img`` (``[H, W]``, ``[H, W, C]`` or channel-first ``[C, H, W]``) as one ``[H, W]`` map (channels averaged)."""
    t = as_hwc(img)
    return t.mean(-1) if t.dim() == 3 else t


def robust_max(a: np.ndarray) -> float:
    """The default top of a colour range: the 99th percentile of the finite values of ``a`` (1.0 when none)."""
    fin = a[np.isfinite(a)]
    return float(np.percentile(fin, 99)) if fin.size else 1.0


def gamma_display(img, exposure: float = 1.0) -> np.ndarray:
    """Linear radiance ``img / exposure`` clipped to 0-1 and shown with gamma 2.2 (the experiments' renders)."""
    return np.clip(img / exposure, 0, 1) ** (1 / 2.2)


def colorize(x, vmin: float = 0.0, vmax: float | None = None, cmap: str = CMAP) -> np.ndarray:
    """A ``[H, W]`` value map as ``[H, W, 3]`` uint8 through ``cmap`` (``vmax``: the 99th percentile by default)."""
    import matplotlib

    a = np.asarray(torch.as_tensor(x).detach().cpu().double())
    if vmax is None:
        vmax = robust_max(a)
    vmax = vmax if vmax > vmin else vmin + 1e-12
    t = np.clip((np.nan_to_num(a, nan=vmin) - vmin) / (vmax - vmin), 0, 1)
    return (matplotlib.colormaps[cmap](t)[..., :3] * 255 + 0.5).astype(np.uint8)


def show_map(fig, ax, value, vmin: float, vmax: float, title: str = "", unit: str = "", fontsize: int = 9,
             masks: dict | None = None):
    """Draw a value map on ``ax`` with the one colormap and a colour bar (shared by every figure).

    ``masks`` ``{label: [H, W] bool}``: pixels left out of the values (clipped in the photo, outside
    the sample, ...), drawn in flat colours that the colormap never uses (:data:`MASK_COLOURS`) and
    named in a legend, so that a left-out pixel is never read as a value of 0.
    """
    import matplotlib.colors as mcolors
    from matplotlib.patches import Patch

    im = ax.imshow(value, cmap=CMAP, vmin=vmin, vmax=vmax if vmax > vmin else vmin + 1e-12, interpolation="nearest")
    handles = []
    for (label, m), colour in zip((masks or {}).items(), MASK_COLOURS):
        m = np.asarray(torch.as_tensor(m).detach().cpu().bool())
        if not m.any():
            continue
        over = np.zeros((*m.shape, 4))
        over[m] = mcolors.to_rgba(colour)
        ax.imshow(over, interpolation="nearest")
        handles.append(Patch(facecolor=colour, label=f"{label} ({int(m.sum())} px)"))
    ax.set_axis_off()
    if title:
        ax.set_title(title, fontsize=fontsize)
    cb = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
    cb.ax.tick_params(labelsize=fontsize - 2)
    if unit:
        cb.set_label(unit, fontsize=fontsize - 1)
    if handles:
        ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.01), fontsize=fontsize - 2,
                  frameon=False, ncol=1, handlelength=1.0)
    return im

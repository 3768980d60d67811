"""Uncertainty: parameter-space std (Eq. 9), image-space std (Eq. 11), posterior-predictive checks, and figures.

* :func:`parameter_std` -- per-site std maps over the particles (Eq. 9).
* :func:`image_std` -- per-pixel std over the particles' renders of any views
  (Eq. 11), batched over particles and chunked over views.
* :func:`predictive_cdf` -- where an observed pixel falls in the
  posterior-predictive distribution (particles' renders plus the likelihood's
  noise): the PIT value, from which interval coverage follows.
* :func:`write_map` -- a value map as EXR (the numbers) and a colour-mapped PNG
  with a colour bar (one fixed colormap, :data:`CMAP`, for every uncertainty
  and error figure, like the paper's).

Example:
    >>> import torch
    >>> from bayes_brdf.posterior import Posterior
    >>> post = Posterior({"roughness": torch.tensor([[0.2], [0.4], [0.3]])}, torch.zeros(3))
    >>> parameter_std(post)["roughness"].tolist()
    [0.10000000149011612]
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from .errors import InputError
from .render.gbuffer import GBUFFERS
from .render.maps import SVBRDF
from .render.shade import shade_chunks
from .render.surface import PlanarSample

#: the one colormap of every uncertainty / error figure
CMAP = "inferno"


def parameter_std(post) -> dict[str, Tensor]:
    """Parameter-space uncertainty (Eq. 9): ``{site: std over particles}`` (Bessel-corrected)."""
    return post.std()


def particle_maps(post) -> SVBRDF:
    """The maps of every particle (``[n, C, H, W]``) of a posterior, or ``post`` itself when it is such maps."""
    if isinstance(post, SVBRDF):
        if post.num_particles is None:
            raise InputError("image-space std needs maps with a particle dimension [n, C, H, W]")
        return post
    return post.maps("all")


def resolve_surface(post, surface):
    """``surface`` when given, else the posterior's (from its file); one line when neither is known."""
    if surface is not None:
        return surface
    s = getattr(post, "surface", None)
    if s is None:
        raise InputError("the sample surface of this posterior is unknown",
                         fix="pass surface= (the capture's observations.surface: a PlanarSample or a Mesh)")
    return s


def particle_renders(post, views, surface: PlanarSample | None = None, *, chunk_views: int | None = None):
    """Yield ``(start, stop, renders [n, v, 3, H, W], mask [v, H, W])`` for chunks of ``views``: every particle, every view.

    ``post`` is a :class:`~bayes_brdf.posterior.Posterior` (with its model) or
    particle maps (:class:`SVBRDF` with a particle dimension). Memory is
    bounded by ``chunk_views`` (default: about 64 M values per chunk).
    """
    maps = particle_maps(post)
    surface = resolve_surface(post, surface)
    views = list(views)
    if not views:
        raise InputError("no views given", fix="pass at least one View")
    g = GBUFFERS.get(tuple(views), surface, dtype=maps.albedo.dtype, device=maps.albedo.device)
    n, (h, w) = maps.num_particles, g.resolution
    if chunk_views is None:
        chunk_views = max(1, (64 * 2**20) // max(1, n * h * w * 3))
    with torch.no_grad():
        for s, e, img in shade_chunks(maps, g, chunk_views=chunk_views):
            yield s, e, img, g.mask[s:e]


def image_std(post, views, surface: PlanarSample | None = None, *, return_mean: bool = False,
              chunk_views: int | None = None):
    """Image-space uncertainty (Eq. 11): per-pixel std ``[V, H, W, 3]`` of the particles' renders of ``views``.

    With ``return_mean=True`` returns ``(std, mean)``. Pixels off the sample are 0.

    Example:
        >>> import torch
        >>> from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
        >>> maps = SVBRDF(torch.rand(4, 3, 8, 8), torch.rand(4, 1, 8, 8) * .5 + .2,
        ...               torch.full((3, 1, 1), .04), torch.tensor([0., 0, 1]).view(3, 1, 1))
        >>> image_std(maps, collocated_views(2, 3.0, resolution=8), PlanarSample(2.0)).shape
        torch.Size([2, 8, 8, 3])
    """
    stds, means = [], []
    for _, _, r, _ in particle_renders(post, views, surface, chunk_views=chunk_views):
        stds.append(r.std(0) if r.shape[0] > 1 else torch.zeros_like(r[0]))
        means.append(r.mean(0))
    std = torch.cat(stds).permute(0, 2, 3, 1)
    return (std, torch.cat(means).permute(0, 2, 3, 1)) if return_mean else std


def predictive_cdf(post, views, images: Tensor, surface: PlanarSample | None = None, *,
                   sigma: float | None = None, kind: str | None = None, chunk_views: int | None = None):
    """PIT values ``F(y) [V, H, W, 3]`` of observed ``images`` under the posterior predictive, and the renders' std.

    The predictive of a pixel is the mixture over particles of the model's
    noise (``Laplace(R(x_i), sigma)``, or Gaussian) around each particle's
    render; ``F`` is its CDF at the observed value, exactly (no quantiles of
    samples). A pixel lies in the central ``p`` interval iff
    ``|F - 1/2| <= p/2``; calibrated predictions give uniform ``F``.
    ``sigma``/``kind`` default to the posterior's (``post.noise_sigma``: the model's
    sigma or the inferred one; ``model.likelihood``). Returns ``(F, std, mean)``, each ``[V, H, W, 3]``.
    """
    model = getattr(post, "model", None)
    sigma = float(sigma if sigma is not None else getattr(post, "noise_sigma", None) or 0)
    kind = kind or getattr(model, "likelihood", "laplace")
    if not sigma > 0:
        raise InputError("the predictive needs the likelihood's noise scale", fix="pass sigma= (image units)")
    y = torch.as_tensor(images)
    Fs, stds, means = [], [], []
    for s, e, r, _ in particle_renders(post, views, surface, chunk_views=chunk_views):
        t = (y[s:e].to(r).permute(0, 3, 1, 2)[None] - r) / sigma
        if kind == "laplace":
            cdf = torch.where(t < 0, 0.5 * torch.exp(t.clamp_max(0)), 1 - 0.5 * torch.exp(-t.clamp_min(0)))
        else:
            cdf = 0.5 * (1 + torch.erf(t / math.sqrt(2)))
        Fs.append(cdf.mean(0))
        stds.append(r.std(0) if r.shape[0] > 1 else torch.zeros_like(r[0]))
        means.append(r.mean(0))
    cat = lambda xs: torch.cat(xs).permute(0, 2, 3, 1)  # noqa: E731
    return cat(Fs), cat(stds), cat(means)


def coverage(pit: Tensor, levels=(0.5, 0.9)) -> dict[str, float]:
    """Fraction of PIT values inside each central interval: ``{"50": ..., "90": ...}``."""
    p = pit.reshape(-1)
    if p.numel() == 0:
        raise InputError("no pixels to measure coverage on")
    return {f"{round(100 * q)}": float(((p - 0.5).abs() <= q / 2).float().mean()) for q in levels}


def correlations(predicted: Tensor, error: Tensor) -> dict[str, float]:
    """Pearson and Spearman correlation between predicted std and absolute error (flattened)."""
    from scipy.stats import pearsonr, spearmanr

    a = predicted.reshape(-1).double().cpu().numpy()
    b = error.reshape(-1).double().cpu().numpy()
    if a.size < 3 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return {"pearson": float("nan"), "spearman": float("nan")}
    return {"pearson": float(pearsonr(a, b)[0]), "spearman": float(spearmanr(a, b)[0])}


# ------------------------------------------------------------------ figures
def colorize(x, vmin: float = 0.0, vmax: float | None = None, cmap: str = CMAP) -> np.ndarray:
    """A ``[H, W]`` value map as ``[H, W, 3]`` uint8 through ``cmap`` (``vmax``: the 99th percentile by default)."""
    import matplotlib

    a = np.asarray(torch.as_tensor(x).detach().cpu().double())
    if vmax is None:
        fin = a[np.isfinite(a)]
        vmax = float(np.percentile(fin, 99)) if fin.size else 1.0
    vmax = vmax if vmax > vmin else vmin + 1e-12
    t = np.clip((np.nan_to_num(a, nan=vmin) - vmin) / (vmax - vmin), 0, 1)
    return (matplotlib.colormaps[cmap](t)[..., :3] * 255 + 0.5).astype(np.uint8)


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


#: colours of pixels a map leaves out (never a colour of :data:`CMAP`): see ``masks`` of :func:`show_map`
MASK_COLOURS = ("#22c3e6", "#8a8a8a", "#3ddc84")


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


def write_map(path, value, *, title: str = "", vmin: float = 0.0, vmax: float | None = None,
              unit: str = "", exr: bool = True, masks: dict | None = None) -> Path:
    """Write ``value`` (``[H, W]``, ``[H, W, C]`` or channel-first ``[C, H, W]``) as ``path.exr`` and a
    colour-mapped ``path.png`` with a colour bar (channels are averaged for the PNG). The EXR is RGB: one
    channel is repeated, two are stored as R, G with B = 0. ``masks`` ``{label: [H, W] bool}`` are pixels
    without a value: NaN in the EXR, a flat colour named in the PNG's legend (:func:`show_map`).
    Both files are written atomically. Returns the PNG path."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .io import write_exr

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
        fin = s[np.isfinite(s)]
        vmax = float(np.percentile(fin, 99)) if fin.size else 1.0
    vmax = vmax if vmax > vmin else vmin + 1e-12
    legend_rows = sum(bool(torch.as_tensor(m).any()) for m in (masks or {}).values())
    fig, ax = plt.subplots(figsize=(3.6, 3.0 + 0.22 * legend_rows), dpi=100)
    show_map(fig, ax, np.ma.masked_invalid(s), vmin, vmax, title, unit, masks=masks)
    fig.tight_layout()
    png = path.with_suffix(".png")
    from .io.outputs import atomic_path
    with atomic_path(png) as tmp:
        fig.savefig(tmp)
    plt.close(fig)
    return png

"""The report's figures: panel grids where every map carries its range, a reliability diagram, std vs error.

Each figure is drawn large enough to read at the width the report shows it (about 1000 px for a
grid, 480 px for a plot) and written atomically as PNG. Value maps use the one colormap
(:data:`~bayes_brdf.uncertainty.CMAP`) with a colour bar; RGB images (photos, renders, albedo) say
their range (``linear 0-1, shown sRGB``) in the title instead.
"""
from __future__ import annotations

import numpy as np
import torch

from .experiments.common import save_figure
from .io.images import linear_to_srgb
from .uncertainty import as_hwc, scalar_map, show_map


def _np(x) -> np.ndarray:
    return np.asarray(torch.as_tensor(x).detach().float().cpu())


def rgb_panel(img, title: str) -> dict:
    """An RGB panel: ``img [H, W, 3]`` (or ``[3, H, W]``) linear in 0-1, shown sRGB (gamma 2.2)."""
    rgb = linear_to_srgb(as_hwc(img).clamp(0, 1)).numpy()
    return {"rgb": rgb, "title": f"{title}\n(RGB, linear 0–1, shown sRGB)"}


def map_panel(value, title: str, vmin: float = 0.0, vmax: float | None = None, masks: dict | None = None) -> dict:
    """A value panel (channels averaged) with a colour bar from ``vmin`` to ``vmax`` (99th percentile by default)."""
    a = scalar_map(value).numpy()
    if vmax is None:
        fin = a[np.isfinite(a)]
        vmax = float(np.percentile(fin, 99)) if fin.size else 1.0
    return {"map": a, "title": title, "vmin": vmin, "vmax": vmax, "masks": masks}


def panel_grid(path, rows: list[list[dict]], *, title: str = "", width: float = 3.1):
    """Rows of panels (:func:`rgb_panel` / :func:`map_panel`, ``None`` for a gap) as one PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ncols = max(len(r) for r in rows)
    fig, axes = plt.subplots(len(rows), ncols, figsize=(width * ncols, (width - 0.1) * len(rows) + (0.4 if title else 0)),
                             squeeze=False)
    for ax in axes.flat:
        ax.set_axis_off()
    for r, row in enumerate(rows):
        for c, p in enumerate(row):
            if p is None:
                continue
            ax = axes[r, c]
            if "rgb" in p:
                ax.imshow(p["rgb"], interpolation="nearest")
                ax.set_title(p["title"], fontsize=10)
                ax.set_axis_off()
            else:
                show_map(fig, ax, p["map"], p["vmin"], p["vmax"], p["title"], fontsize=11, masks=p.get("masks"))
    if title:
        fig.suptitle(title, fontsize=12)
    fig.tight_layout(w_pad=2.0)
    return save_figure(fig, path, dpi=90)


def reliability(path, curves: dict, *, title: str = "Are the intervals calibrated?"):
    """Nominal vs observed coverage of central intervals: ``curves = {label: (nominal, observed)}``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.0, 5.4))
    ax.plot([0, 1], [0, 1], color="0.6", lw=1, ls="--", label="calibrated")
    for lab, (nom, obs) in curves.items():
        ax.plot(nom, obs, marker="o", ms=4, label=lab)
    ax.set_xlim(0, 1), ax.set_ylim(0, 1)
    ax.set_xlabel("nominal coverage of the central interval", fontsize=11)
    ax.set_ylabel("observed fraction inside", fontsize=11)
    ax.set_title(title, fontsize=11)
    ax.text(0.62, 0.08, "below the line:\nintervals too narrow", fontsize=9, color="0.35")
    ax.text(0.04, 0.84, "above: too wide", fontsize=9, color="0.35")
    ax.tick_params(labelsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=9, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=1, frameon=False)
    fig.tight_layout()
    return save_figure(fig, path, dpi=100)


def std_vs_error(path, panels: list[tuple], *, bins: int = 12):
    """Binned mean |error| against predicted std, one panel per ``(std, |error|, title)``: a calibrated
    posterior's points follow ``|error| ~ 0.8 std`` (Gaussian; Laplace 0.71); dots are the pixels."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(panels), figsize=(4.8 * len(panels), 4.2), squeeze=False)
    for ax, (s, e, title) in zip(axes[0], panels):
        s, e = _np(s).reshape(-1), _np(e).reshape(-1)
        ok = np.isfinite(s) & np.isfinite(e)
        s, e = s[ok], e[ok]
        rng = np.random.default_rng(0)
        pick = rng.choice(s.size, size=min(s.size, 4000), replace=False)
        ax.scatter(s[pick], e[pick], s=2, alpha=0.15, color="0.4", label="pixels / texels")
        edges = np.unique(np.quantile(s, np.linspace(0, 1, bins + 1)))
        idx = np.clip(np.searchsorted(edges, s, side="right") - 1, 0, len(edges) - 2)
        xs = [s[idx == i].mean() for i in range(len(edges) - 1) if (idx == i).any()]
        ys = [e[idx == i].mean() for i in range(len(edges) - 1) if (idx == i).any()]
        ax.plot(xs, ys, marker="o", color="tab:orange", label="mean |error| per std bin")
        top = float(np.quantile(s, 0.995)) if s.size else 1.0
        ax.plot([0, top], [0, 0.8 * top], ls="--", color="tab:blue", lw=1, label="|error| = 0.8 std (calibrated)")
        ax.set_xlim(0, top), ax.set_ylim(0, max(float(np.quantile(e, 0.995)), 0.8 * top) if e.size else 1)
        ax.set_xlabel("predicted std", fontsize=11)
        ax.set_ylabel("|error|", fontsize=11)
        ax.set_title(title, fontsize=11)
        ax.tick_params(labelsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    return save_figure(fig, path, dpi=100)


def bands(path, series: dict, *, xlabel: str, ylabel: str, title: str = ""):
    """``series = {label: (xs, mean, sd)}``: lines with a shaded band of one standard deviation."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.2, 4.0))
    for lab, (xs, m, sd) in series.items():
        xs, m, sd = (np.asarray(v, dtype=float) for v in (xs, m, sd))
        ax.plot(xs, m, marker="o", ms=4, label=lab)
        ax.fill_between(xs, m - sd, m + sd, alpha=0.2)
    ax.set_xlabel(xlabel, fontsize=11)
    ax.set_ylabel(ylabel, fontsize=11)
    if title:
        ax.set_title(title, fontsize=11)
    ax.tick_params(labelsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path, dpi=100)


def interval_coverage(particles: torch.Tensor, truth: torch.Tensor, levels) -> list[float]:
    """Fraction of ``truth`` values inside the particles' central intervals (empirical quantiles over dim 0)."""
    out = []
    for q in levels:
        lo = torch.quantile(particles.float(), 0.5 - q / 2, dim=0)
        hi = torch.quantile(particles.float(), 0.5 + q / 2, dim=0)
        out.append(float(((truth >= lo) & (truth <= hi)).float().mean()))
    return out


def plot_candidates(path, cands, scores, picks, title, centre=(0.0, 0.0, 0.0)):
    """Candidate views seen from above (camera directions from ``centre``, the scene's), coloured by ``scores``;
    ``picks`` ringed and numbered."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .uncertainty import CMAP
    d = np.array([v.camera.position for v in cands], dtype=float) - np.asarray(centre, dtype=float)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    fig, ax = plt.subplots(figsize=(4.2, 3.8))
    sc = ax.scatter(d[:, 0], d[:, 1], c=scores, cmap=CMAP, s=18)
    ax.scatter(d[picks, 0], d[picks, 1], s=120, facecolors="none", edgecolors="tab:cyan", linewidths=2,
               label="recommended")
    for rank, i in enumerate(picks):
        ax.annotate(str(rank + 1), d[i, :2], xytext=(4, 4), textcoords="offset points", color="tab:cyan", fontsize=9)
    ax.add_patch(plt.Circle((0, 0), 1, fill=False, color="gray", lw=0.5))
    ax.set_aspect("equal")
    ax.set_xlabel("camera direction x")
    ax.set_ylabel("camera direction y")
    ax.set_title(title, fontsize=9)
    fig.colorbar(sc, ax=ax, fraction=0.046, pad=0.04, label="MI score, nats (only differences matter)")
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)

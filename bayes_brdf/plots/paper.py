"""The layouts of the paper's figures that one experiment draws (Figs. 4, 5 and 6 of
:mod:`bayes_brdf.experiments`): renders next to their std and error maps, one colour range per row."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .base import CMAP, gamma_display, pyplot, save_figure


def fig4_overview(path, view_names: list, truth, estimates: dict, stds, vmaxes) -> Path:
    """Two rows per novel view: the true render and each estimate's render on top; below, the image-space std
    and each estimate's |error| (one colour range per view, ``vmaxes[v]``, shared by its std and error maps).

    ``truth[v]`` and renders ``[H, W, 3]`` linear (shown gamma 2.2, exposed at the truth's 99.5th percentile);
    ``estimates = {label: (short label, renders [V], |errors| [V])}``; ``stds [V, H, W]``."""
    plt = pyplot()
    nv = len(view_names)
    fig, axes = plt.subplots(2 * nv, 1 + len(estimates), figsize=(11.2, 4.3 * nv), squeeze=False)
    for v, name in enumerate(view_names):
        vmax = vmaxes[v]
        exposure = float(np.percentile(truth[v], 99.5)) or 1.0
        top, bot = axes[2 * v], axes[2 * v + 1]
        top[0].imshow(gamma_display(truth[v], exposure), interpolation="nearest")
        top[0].set_title(f"{name}: truth", fontsize=8)
        im = bot[0].imshow(stds[v], cmap=CMAP, vmin=0, vmax=vmax, interpolation="nearest")
        bot[0].set_title(f"{name}: std (Eq. 11)", fontsize=8)
        for j, (label, (short, renders, errors)) in enumerate(estimates.items()):
            top[j + 1].imshow(gamma_display(renders[v], exposure), interpolation="nearest")
            top[j + 1].set_title(label, fontsize=8)
            bot[j + 1].imshow(errors[v], cmap=CMAP, vmin=0, vmax=vmax, interpolation="nearest")
            bot[j + 1].set_title(f"|error| {short}", fontsize=8)
        for ax in (*top, *bot):
            ax.set_axis_off()
        cb = fig.colorbar(im, ax=list(bot), fraction=0.02, pad=0.01)
        cb.ax.tick_params(labelsize=7)
        cb.set_label("radiance (|error| and std)", fontsize=7)
        fig.colorbar(im, ax=list(top), fraction=0.02, pad=0.01).ax.set_visible(False)   # keep the columns aligned
    return save_figure(fig, path, dpi=90, tight=True)


#: the columns of :func:`fig5_overview`: ``(key of a result, title)``; ``"render"`` is an RGB render
FIG5_COLUMNS = (("render", "novel view: MAP render"), ("rough_map", "roughness (MAP)"),
                ("rough_std", "roughness std (Eq. 9)"), ("albedo_err", "|albedo error| (MAP)"),
                ("img_std", "novel-view std (Eq. 11)"))


def fig5_overview(path, results: dict, truth_render, hist: dict, vmaxes: dict, truth_value: float, *,
                  title: str, hist_label: str) -> Path:
    """One row per setting (``results = {label: {key: map}}``, keys of :data:`FIG5_COLUMNS`; the value maps
    with one range per column, ``vmaxes[key]``), and beside them the histograms of ``hist = {label: values}``
    with ``truth_value`` marked. Renders are exposed at the 99th percentile of ``truth_render``."""
    plt = pyplot()
    fig = plt.figure(figsize=(14.5, 5.6))
    gs = fig.add_gridspec(2, 7, width_ratios=[1, 1, 1, 1, 1, 0.12, 1.5], wspace=0.35, hspace=0.25)
    exposure = float(np.percentile(truth_render, 99.0)) or 1.0
    for r, (label, res) in enumerate(results.items()):
        for c, (key, col) in enumerate(FIG5_COLUMNS):
            ax = fig.add_subplot(gs[r, c])
            ax.set_axis_off()
            if key == "render":
                ax.imshow(gamma_display(res[key], exposure), interpolation="nearest")
            else:
                im = ax.imshow(res[key], cmap=CMAP, vmin=0, vmax=vmaxes[key], interpolation="nearest")
                cb = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03)
                cb.ax.tick_params(labelsize=6)
            ax.set_title(f"{col}\n{label}", fontsize=7)
    ax = fig.add_subplot(gs[:, 6])
    bins = np.linspace(0.05, 1.0, 39)
    for label, values in hist.items():
        ax.hist(values, bins=bins, alpha=0.6, density=True, label=label)
    ax.axvline(truth_value, color="k", ls="--", lw=1, label="truth")
    ax.set_xlabel(hist_label, fontsize=8)
    ax.set_ylabel("density", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=9)
    return save_figure(fig, path, dpi=85, tight=True)


def fig6_overview(path, rows: list, *, title: str) -> Path:
    """One row per held-out photo: ``rows = [(title, photo [H, W, 3], {model: {"pred", "err", "std" [H, W, 3],
    "spearman"}})]``; the photo, then per model its MAP render, |error| and std (channels averaged; one colour
    range per row, the largest 99th percentile of its errors and stds)."""
    plt = pyplot()
    ncol = 1 + 3 * len(rows[0][2])
    fig, axes = plt.subplots(len(rows), ncol, figsize=(2.0 * ncol, 2.2 * len(rows)), squeeze=False)
    for r, (name, photo, per_model) in enumerate(rows):
        axes[r, 0].imshow(gamma_display(photo))
        axes[r, 0].set_title(f"{name}\nheld-out photo", fontsize=8)
        vmax = max(float(np.quantile(np.concatenate([p["err"].ravel(), p["std"].ravel()]), 0.99))
                   for p in per_model.values()) or 1.0
        for m, (model, p) in enumerate(per_model.items()):
            c = 1 + 3 * m
            axes[r, c].imshow(gamma_display(p["pred"]))
            axes[r, c].set_title(f"{model}: MAP render", fontsize=8)
            axes[r, c + 1].imshow(p["err"].mean(-1), cmap=CMAP, vmin=0, vmax=vmax)
            axes[r, c + 1].set_title("|MAP - photo|", fontsize=8)
            im = axes[r, c + 2].imshow(p["std"].mean(-1), cmap=CMAP, vmin=0, vmax=vmax)
            axes[r, c + 2].set_title(f"std (Eq. 11), Spearman {p['spearman']:.2f}", fontsize=8)
        fig.colorbar(im, ax=axes[r, -1], fraction=0.046)
    for ax in axes.ravel():
        ax.set_xticks([]), ax.set_yticks([])
    fig.suptitle(title, fontsize=9)
    return save_figure(fig, path, tight=True)

"""Where the views are: candidate camera directions seen from above, coloured by their score
(:func:`plot_candidates`), and the views each capture method added, round by round (:func:`views_polar`)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .base import CMAP, pyplot, save_figure


def plot_candidates(path, cands, scores, picks, title, centre=(0.0, 0.0, 0.0)) -> Path:
    """Candidate views seen from above (camera directions from ``centre``, the scene's), coloured by ``scores``;
    ``picks`` ringed and numbered."""
    plt = pyplot()
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
    return save_figure(fig, path, dpi=110)


def views_polar(path, panels: dict, *, rounds: int, lights: bool, title: str) -> Path:
    """One polar panel per method, ``panels = {title: [runs]}``; a run is a list of ``(round, directions)``
    (round 0: the initial views), ``directions`` a list of ``((zenith, azimuth) of the camera, (zenith,
    azimuth) of its light)`` in degrees. Radius: the zenith angle; colour: the round (``rounds`` in all);
    ``lights``: the lights as crosses of their camera's colour."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(panels), subplot_kw={"projection": "polar"}, figsize=(7.6, 3.9))
    cmap = plt.get_cmap("viridis")
    for ax, (name, runs) in zip(axes, panels.items()):
        for s, groups in enumerate(runs):
            for rnd, dirs in groups:
                if not dirs:
                    continue
                colour, lab = ("0.55", "initial") if rnd == 0 else (cmap((rnd - 1) / max(rounds - 1, 1)),
                                                                     f"round {rnd}")
                ax.scatter([math.radians(c[1]) for c, _ in dirs], [c[0] for c, _ in dirs], s=14, color=colour,
                           label=lab if s == 0 else None, edgecolors="k", linewidths=0.3, zorder=3)
                if lights:
                    ax.scatter([math.radians(lt[1]) for _, lt in dirs], [lt[0] for _, lt in dirs], s=14, marker="x",
                               color=colour, linewidths=0.8, zorder=2)
        ax.set_ylim(0, 90)
        ax.set_yticks([30, 60, 90])
        ax.tick_params(labelsize=6)
        ax.set_title(name, fontsize=8)
    axes[-1].legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.05, 1.0))
    fig.suptitle(title, fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)

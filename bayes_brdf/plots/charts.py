"""Charts: lines over a count with their spread (:func:`line_plot`), the reliability diagram of interval
coverage (:func:`reliability`) and predicted std against the actual error (:func:`std_vs_error`)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .base import as_numpy, pyplot, save_figure

#: the two looks of a chart: the experiments' (compact, the paper's) and the report's (read at about 480 px
#: wide) -- figure size in inches, marker size, font sizes of the axis labels, ticks, title and legend (``None``:
#: matplotlib's), dpi
CHART_STYLES = {"compact": dict(size=(4.2, 3.2), ms=3, label=None, ticks=None, title=9, legend=7, dpi=110),
                "report": dict(size=(5.2, 4.0), ms=4, label=11, ticks=10, title=11, legend=9, dpi=100)}


def _axes(ax, xlabel: str, ylabel: str, title: str, st: dict) -> None:
    """Axis labels, the title (when there is one), tick labels and the grid of a chart in style ``st``."""
    size = {} if st["label"] is None else {"fontsize": st["label"]}
    ax.set_xlabel(xlabel, **size)
    ax.set_ylabel(ylabel, **size)
    if title:
        ax.set_title(title, fontsize=st["title"])
    if st["ticks"] is not None:
        ax.tick_params(labelsize=st["ticks"])
    ax.grid(alpha=0.3)


def line_plot(path, series: dict, *, xlabel: str, ylabel: str, title: str = "", logx: bool = False,
              spread: str = "bars", style: str = "compact", line_styles: dict | None = None,
              legend: str = "inside") -> Path:
    """``series = {label: (xs, ys)}`` or ``{label: (xs, ys, sd)}`` as lines on one plot, written to ``path``.

    A third entry is drawn as error bars (``spread="bars"``) or as a shaded band of ``ys ± sd``
    (``spread="band"``). ``logx``: a log-2 x axis. ``style``: a key of :data:`CHART_STYLES`.
    ``line_styles``: ``{label: matplotlib line keywords}`` (e.g. one colour per group, one dash per
    quantity). ``legend="right"`` puts the legend beside the axes, where it hides no line.
    """
    st = CHART_STYLES[style]
    wide = legend == "right"
    w, h = st["size"]
    fig, ax = pyplot().subplots(figsize=(w * 1.7, h) if wide else st["size"])
    for lab, (xs, ys, *sd) in series.items():
        kw = dict((line_styles or {}).get(lab, {}))
        if sd and spread == "band":
            xs, m, s = (np.asarray(v, dtype=float) for v in (xs, ys, sd[0]))
            (line,) = ax.plot(xs, m, marker="o", ms=st["ms"], label=lab, **kw)
            ax.fill_between(xs, m - s, m + s, alpha=0.2, color=line.get_color())
        elif sd:
            ax.errorbar(xs, ys, yerr=sd[0], marker="o", ms=st["ms"], capsize=2, label=lab, **kw)
        else:
            ax.plot(xs, ys, marker="o", ms=st["ms"], label=lab, **kw)
    if logx:
        ax.set_xscale("log", base=2)
    _axes(ax, xlabel, ylabel, title, st)
    if wide:
        ax.legend(fontsize=st["legend"], loc="center left", bbox_to_anchor=(1.02, 0.5), frameon=False)
    else:
        ax.legend(fontsize=st["legend"])
    fig.tight_layout()
    return save_figure(fig, path, dpi=st["dpi"])


def reliability(path, curves: dict, *, title: str = "Are the intervals calibrated?") -> Path:
    """Nominal vs observed coverage of central intervals: ``curves = {label: (nominal, observed)}``."""
    fig, ax = pyplot().subplots(figsize=(5.0, 5.4))
    ax.plot([0, 1], [0, 1], color="0.6", lw=1, ls="--", label="calibrated")
    for lab, (nom, obs) in curves.items():
        ax.plot(nom, obs, marker="o", ms=4, label=lab)
    ax.set_xlim(0, 1), ax.set_ylim(0, 1)
    ax.text(0.62, 0.08, "below the line:\nintervals too narrow", fontsize=9, color="0.35")
    ax.text(0.04, 0.84, "above: too wide", fontsize=9, color="0.35")
    _axes(ax, "nominal coverage of the central interval", "observed fraction inside", title, CHART_STYLES["report"])
    ax.legend(fontsize=9, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=1, frameon=False)
    fig.tight_layout()
    return save_figure(fig, path, dpi=100)


def std_vs_error(path, panels: list[tuple], *, bins: int = 12) -> Path:
    """Binned mean |error| against predicted std, one panel per ``(std, |error|, title)``: a calibrated
    posterior's points follow ``|error| ~ 0.8 std`` (Gaussian; Laplace 0.71); dots are the pixels."""
    fig, axes = pyplot().subplots(1, len(panels), figsize=(4.8 * len(panels), 4.2), squeeze=False)
    for ax, (s, e, title) in zip(axes[0], panels):
        s, e = as_numpy(s).reshape(-1), as_numpy(e).reshape(-1)
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
        _axes(ax, "predicted std", "|error|", title, CHART_STYLES["report"])
        ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    return save_figure(fig, path, dpi=100)

"""A small self-contained HTML report: headings, paragraphs, tables and images (embedded as base64),
so the one file opens in any browser and can be mailed around.

Example:
    >>> r = Report("demo")
    >>> r.heading("Numbers"); r.table([["views", 5]], header=["what", "value"])
    >>> "<table>" in r.html()
    True
"""
from __future__ import annotations

import base64
import html
from pathlib import Path

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;max-width:1100px;margin:2em auto;
padding:0 1em;color:#222;line-height:1.45}
h1{font-size:1.6em;border-bottom:2px solid #444}h2{font-size:1.25em;margin-top:1.6em;border-bottom:1px solid #ccc}
figure{display:inline-block;margin:.3em .5em;vertical-align:top;text-align:center}
figure img{max-width:100%;image-rendering:pixelated;border:1px solid #ddd}
figcaption{font-size:.85em;color:#444;margin:.2em auto 0}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em}td,th{border:1px solid #ccc;padding:.25em .6em;text-align:right}
th{background:#f3f3f3}code,pre{background:#f6f6f6;padding:.1em .3em;border-radius:3px}
pre{padding:.6em;overflow-x:auto}.note{color:#555;font-size:.9em}
"""


def lighting(view) -> str:
    """How a view is lit, in words: its point lights (a collocated flash or a lamp, with its power) and its
    environment light (the map's name, size, scale), e.g. ``"flash (power 10) + environment 'studio' 32x64"``.

    Example:
        >>> from bayes_brdf.render.cameras import PerspectiveCamera
        >>> from bayes_brdf.render.environment import studio
        >>> from bayes_brdf.render.views import View
        >>> v = View.collocated(PerspectiveCamera(position=(0, 0, 3)), power=10)
        >>> lighting(v), lighting(View(v.camera, (studio(8),)))
        ('flash (power 10)', "environment 'studio' 16x8, scale 1 (alone)")
    """
    parts = []
    cam = tuple(float(x) for x in view.camera.position)
    for light in view.point_lights:
        pw = sorted(set(round(float(x), 4) for x in light.power))
        power = f"power {pw[0]:g}" if len(pw) == 1 else "power " + "/".join(f"{float(x):g}" for x in light.power)
        at = "" if tuple(light.position) == cam else f" at {tuple(round(float(x), 3) for x in light.position)}"
        parts.append(("flash" if not at else "point light") + f" ({power}){at}")
    env = view.environment
    if env is not None:
        h, w, _ = env.radiance.shape
        parts.append(f"environment '{env.name or env.digest}' {w}x{h}, scale {env.scale:g}"
                     + ("" if parts else " (alone)"))
    return " + ".join(parts)


class Report:
    """Collects blocks and writes one HTML file (:meth:`write`)."""

    def __init__(self, title: str):
        self.title = title
        self.blocks: list[str] = []

    def heading(self, text: str):
        self.blocks.append(f"<h2>{html.escape(text)}</h2>")

    def text(self, text: str, cls: str = ""):
        c = f' class="{cls}"' if cls else ""
        self.blocks.append(f"<p{c}>{html.escape(text)}</p>")

    def code(self, text: str):
        self.blocks.append(f"<pre><code>{html.escape(text)}</code></pre>")

    def images(self, items, width: int = 256):
        """``items``: ``[(png path, caption)]`` shown side by side."""
        figs = []
        for path, cap in items:
            data = base64.b64encode(Path(path).read_bytes()).decode()
            figs.append(f'<figure style="max-width:{width}px"><img src="data:image/png;base64,{data}" '
                        f'width="{width}" alt="{html.escape(cap)}">'
                        f"<figcaption>{html.escape(cap)}</figcaption></figure>")
        self.blocks.append("<div>" + "".join(figs) + "</div>")

    def table(self, rows, header=None):
        def cell(v, tag="td"):
            if isinstance(v, float):
                v = f"{v:.4g}"
            elif v is None:
                v = "–"
            return f"<{tag}>{html.escape(str(v))}</{tag}>"
        head = "<tr>" + "".join(cell(h, "th") for h in header) + "</tr>" if header else ""
        body = "".join("<tr>" + "".join(cell(v) for v in r) + "</tr>" for r in rows)
        self.blocks.append(f"<table>{head}{body}</table>")

    def views(self, views, roles=None, indices=None):
        """A table of ``views``: index, role (``roles[i]``, e.g. fitted / held out), camera and **lighting**
        (:func:`lighting`), so a reader sees which photos were lit by a flash and which by an environment."""
        idx = list(range(len(views))) if indices is None else list(indices)
        rows = []
        for k, (i, v) in enumerate(zip(idx, views)):
            p = tuple(round(float(x), 3) for x in v.camera.position)
            rows.append([i] + ([roles[k]] if roles is not None else []) + [f"{type(v.camera).__name__} at {p}",
                                                                           lighting(v)])
        self.table(rows, header=["view"] + (["role"] if roles is not None else []) + ["camera", "lighting"])

    def html(self) -> str:
        return (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(self.title)}</title>"
                f"<style>{_CSS}</style></head><body><h1>{html.escape(self.title)}</h1>"
                + "\n".join(self.blocks) + "</body></html>")

    def write(self, path) -> Path:
        from .io.outputs import write_text

        return write_text(path, self.html())

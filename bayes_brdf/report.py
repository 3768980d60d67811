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

    def html(self) -> str:
        return (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(self.title)}</title>"
                f"<style>{_CSS}</style></head><body><h1>{html.escape(self.title)}</h1>"
                + "\n".join(self.blocks) + "</body></html>")

    def write(self, path) -> Path:
        from .io.outputs import write_text

        return write_text(path, self.html())

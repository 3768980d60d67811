"""Griffe extension used only by the documentation build (never imported by the package).

The package's docstrings are Google style, with two habits that Markdown does not
understand out of the box. This extension rewrites the docstring *text* that
mkdocstrings renders (the source files are untouched):

* ``Example:`` sections become ``Examples:`` so griffe renders the ``>>>`` lines
  as highlighted code (griffe only knows the plural as the examples section);
* reStructuredText roles (``:func:`name```, ``:class:`~a.b.C```, ...) become
  inline code (`` `name` ``, `` `C` ``);
* a paragraph ending in ``::`` (an RST literal block marker) ends in ``:``
  instead; the indented block after it is already a Markdown code block;
* RST "simple tables" (columns framed by ``=====  =====`` lines) become
  Markdown tables.

Enabled in ``mkdocs.yml`` under ``plugins: mkdocstrings: handlers: python:
options: extensions``.
"""
from __future__ import annotations

import re

import griffe

_ROLE = re.compile(r":(?:class|func|meth|mod|data|attr|obj|exc|const):`~?([^`]+)`")
_EXAMPLE = re.compile(r"^(\s*)Example:\s*$", re.MULTILINE)
_LITERAL = re.compile(r"(\S)::$", re.MULTILINE)
_BORDER = re.compile(r"^\s*=+(?:\s+=+)+\s*$")


def _role(m: re.Match) -> str:
    target = m.group(1)
    if m.group(0).split("`", 1)[1].startswith("~"):
        target = target.rsplit(".", 1)[-1]
    return f"`{target}`"


def _columns(border: str) -> list[tuple[int, int]]:
    return [(m.start(), m.end()) for m in re.finditer(r"=+", border)]


def _table(lines: list[str]) -> list[str]:
    """One RST simple table (border, header, border, rows..., border) as Markdown lines."""
    indent = re.match(r"\s*", lines[0]).group(0)
    cols = _columns(lines[0])
    rows: list[list[str]] = []
    header: list[str] | None = None
    for line in lines[1:]:
        if _BORDER.match(line):
            if header is None:
                header, rows = (rows[0] if rows else [""] * len(cols)), []
            continue
        if not line.strip():
            continue
        cells = []
        for k, (a, _) in enumerate(cols):
            b = cols[k + 1][0] if k + 1 < len(cols) else len(line)
            cells.append(line[a:b].strip())
        if rows and not cells[0]:  # continuation line of the previous row
            rows[-1] = [f"{p} {c}".strip() for p, c in zip(rows[-1], cells)]
        else:
            rows.append(cells)
    header = header or [""] * len(cols)

    def fmt(cells):
        return indent + "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"

    return [fmt(header), indent + "|" + "|".join("---" for _ in cols) + "|", *(fmt(r) for r in rows)]


def _tables(text: str) -> str:
    lines = text.split("\n")
    out: list[str] = []
    i = 0
    while i < len(lines):
        if _BORDER.match(lines[i]):
            # a simple table has exactly three border lines: top, under the header, bottom
            borders = [j for j in range(i, len(lines)) if _BORDER.match(lines[j])][:3]
            if len(borders) == 3:
                out.extend(_table(lines[borders[0]:borders[2] + 1]))
                i = borders[2] + 1
                continue
        out.append(lines[i])
        i += 1
    return "\n".join(out)


def rewrite(text: str) -> str:
    """The Markdown-friendly version of one docstring."""
    text = _EXAMPLE.sub(r"\1Examples:", text)
    text = _ROLE.sub(_role, text)
    text = _LITERAL.sub(r"\1:", text)
    return _tables(text)


class RstToMarkdown(griffe.Extension):
    """Rewrite every docstring of the loaded objects (see the module docstring)."""

    def on_instance(self, *, obj: griffe.Object, **kwargs) -> None:  # noqa: D102
        if obj.docstring is not None:
            obj.docstring.value = rewrite(obj.docstring.value)

"""The documentation: the generated CLI reference covers the parsers, and the maths is served locally."""
from __future__ import annotations

import argparse
import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from bayes_brdf.cli.main import build_parser

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
HOOK = DOCS / "hooks" / "cli_reference.py"
REMOTE = re.compile(r"^(?:[a-z][a-z0-9+.-]*:)?//", re.I)  # http://, https://, protocol-relative //
CDN_HINTS = ("unpkg.com", "cdn.", "jsdelivr", "cdnjs", "mathjax", "googleapis")


def _hook():
    spec = importlib.util.spec_from_file_location("bayes_brdf_docs_cli_reference", HOOK)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _mkdocs_yml() -> dict:
    yaml = pytest.importorskip("yaml")  # comes with mkdocs (the docs extra)

    class Loader(yaml.SafeLoader):
        pass

    # mkdocs.yml may use !ENV or !!python/name: tags; their values do not matter here
    Loader.add_multi_constructor("", lambda loader, suffix, node: None)
    return yaml.load((ROOT / "mkdocs.yml").read_text(), Loader=Loader)


def _commands(parser: argparse.ArgumentParser, path: tuple[str, ...]):
    """(path, parser) for ``parser`` and every subcommand below it, walked independently of the hook."""
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _commands(sub, path + (name,))


def _section(text: str, title: str) -> str:
    """The part of the generated page from the heading `title` to the next heading."""
    m = re.search(rf"^#+ `{re.escape(title)}`.*$", text, re.M)
    assert m, f"no heading for '{title}' in the CLI reference"
    nxt = re.search(r"^#", text[m.end():], re.M)
    return text[m.end(): m.end() + nxt.start()] if nxt else text[m.end():]


# ------------------------------------------------------------------ CLI reference
def test_cli_reference_covers_every_command_and_option():
    parser = build_parser()
    text = _hook().render_cli_reference(parser)
    commands = list(_commands(parser, (parser.prog,)))
    assert {p[-1] for p, _ in commands[1:]} >= {"render", "inspect", "infer", "fit", "recommend", "demo",
                                                 "compare", "experiment"}
    for path, sub in commands:
        body = _section(text, " ".join(path))
        assert "usage: " + " ".join(path) in body
        if sub.description:
            assert " ".join(sub.description.split())[:30].replace("``", "`") in body.replace("\\", "")
        for action in sub._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name in action.choices:
                    assert f"`{name}`" in body, f"{' '.join(path)}: command {name} not listed"
                continue
            for opt in action.option_strings:
                assert re.search(rf"^\| `[^`|]*(?<![\w-]){re.escape(opt)}(?![\w-])[^`]*` \|", body, re.M), \
                    f"{' '.join(path)}: option {opt} has no row"
            if not action.option_strings:
                m = action.metavar or action.dest
                shown = f"{m} [{m} ...]" if action.nargs == argparse.ONE_OR_MORE else m     # fit-many CAPTURE...
                assert f"`{shown}`" in body, f"{' '.join(path)}: argument {action.dest}"
            if action.option_strings and action.nargs != 0 and action.default not in (None, [], argparse.SUPPRESS):
                assert f"`{action.default}`" in body, f"{' '.join(path)}: default of {action.dest}"


def test_cli_reference_is_wired_into_the_build():
    cfg = _mkdocs_yml()
    assert "docs/hooks/cli_reference.py" in cfg["hooks"]
    assert {"CLI reference": "cli.md"} in cfg["nav"]
    assert _hook().MARKER in (DOCS / "cli.md").read_text()


def test_cli_reference_escapes_markdown():
    md = _hook()._md("a ``x|y`` b_c *d* $e$ <f> [g](h) p|q")
    assert "`x|y`" in md and r"b\_c" in md and r"\*d\*" in md and "$" not in md and "<f>" not in md
    assert r"\[g\]" in md and "p&#124;q" in md


def test_api_reference_has_every_cli_module_and_presets():
    text = (DOCS / "reference" / "cli.md").read_text()
    for f in sorted((ROOT / "bayes_brdf" / "cli").glob("*.py")):
        if f.stem != "__init__":
            assert f"::: bayes_brdf.cli.{f.stem}\n" in text, f"docs/reference/cli.md lacks bayes_brdf.cli.{f.stem}"
    assert "::: bayes_brdf.presets\n" in (DOCS / "reference" / "presets.md").read_text()
    nav = _mkdocs_yml()["nav"]
    api = next(e["API reference"] for e in nav if isinstance(e, dict) and "API reference" in e)
    assert {"cli": "reference/cli.md"} in api and {"presets": "reference/presets.md"} in api


# ------------------------------------------------------------------ maths served with the site
def test_maths_assets_are_local_and_present():
    cfg = _mkdocs_yml()
    text = (ROOT / "mkdocs.yml").read_text().lower()
    assert not [h for h in CDN_HINTS if h in text], "mkdocs.yml names a CDN"
    refs = [(e["path"] if isinstance(e, dict) else e) for e in cfg.get("extra_javascript", []) + cfg.get("extra_css", [])]
    assert any("katex.min.js" in r for r in refs) and any("katex.min.css" in r for r in refs)
    for ref in refs:
        assert not REMOTE.match(ref), f"remote asset in mkdocs.yml: {ref}"
        assert (DOCS / ref).is_file(), f"mkdocs.yml names docs/{ref}, which does not exist"
    assert cfg["theme"].get("font") is False, "theme.font loads web fonts from the network"
    katex = DOCS / "assets" / "katex"
    assert "MIT" in (katex / "LICENSE").read_text()
    css = (katex / "katex.min.css").read_text()
    woff2 = re.findall(r"url\(([^)]+\.woff2)\)", css)
    assert len(woff2) >= 15
    for f in woff2:
        assert not REMOTE.match(f) and (katex / f).is_file(), f"katex.min.css needs {f}"
    for f in (katex / "katex.min.js", katex / "katex.min.css", DOCS / "javascripts" / "katex.js"):
        urls = [u for u in re.findall(r"https?://[^\s\"')]+", f.read_text()) if "www.w3.org" not in u]
        assert not urls, f"{f.name} loads {urls}"
    for md in DOCS.rglob("*.md"):  # no page pulls a script or stylesheet of its own from the network
        assert not re.search(r"<(script|link)[^>]+(src|href)=[\"']?(https?:)?//", md.read_text()), md


@pytest.mark.slow
def test_strict_build_has_only_local_maths(tmp_path):
    """The real ``mkdocs build --strict`` (about 15 s on 2 cores): no remote script or stylesheet,
    the KaTeX files in the site, the CLI page generated."""
    pytest.importorskip("mkdocs")
    site = tmp_path / "site"
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(site)],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    pages = list(site.rglob("*.html"))
    assert len(pages) > 20
    tag = re.compile(r"<(?:script|link)\b[^>]*>", re.I)
    for page in pages:
        html = page.read_text()
        for t in tag.findall(html):
            src = re.search(r"(?:src|href)=[\"']?([^\"' >]+)", t)
            if src and ("stylesheet" in t or t.lower().startswith("<script")):
                assert not REMOTE.match(src.group(1)), f"{page.relative_to(site)}: {t}"
        low = html.lower()
        assert "unpkg.com" not in low and "cdn." not in low and "mathjax" not in low, page
    concepts = (site / "concepts" / "index.html").read_text()
    assert 'class="arithmatex"' in concepts and "assets/katex/katex.min.js" in concepts
    assert (site / "assets" / "katex" / "fonts" / "KaTeX_Main-Regular.woff2").is_file()
    cli = (site / "cli" / "index.html").read_text()
    assert _hook().MARKER not in cli and "<table>" in cli
    for name in ("render", "inspect", "infer", "fit", "recommend", "demo", "compare", "experiment"):
        assert f"bayes-brdf {name}" in cli

"""MkDocs hook: the CLI reference page, generated from the argparse parsers at build time.

``docs/cli.md`` holds the marker ``<!-- cli-reference -->``; :func:`on_page_markdown`
replaces it with :func:`render_cli_reference` of ``bayes_brdf.cli.main.build_parser()``,
so the page cannot drift from ``bayes-brdf COMMAND --help``. The generator is a plain
function too (``tests/test_docs.py`` calls it without mkdocs).
"""
from __future__ import annotations

import argparse
import functools
import html
import logging
import re

MARKER = "<!-- cli-reference -->"
PAGE = "cli.md"
USAGE_WIDTH = 72

log = logging.getLogger("mkdocs.hooks.cli_reference")


def parser_parts(parser: argparse.ArgumentParser):
    """``(actions, exclusive_groups, subcommands)`` of ``parser``.

    argparse has no public API to walk a parser, so every private attribute this
    module reads is read here: ``_actions`` (arguments in the order added),
    ``_mutually_exclusive_groups`` and, of a ``_SubParsersAction``, ``choices``
    (name -> parser, aliases included) and ``_choices_actions`` (the one-line helps).
    ``subcommands`` is a list of ``(name, aliases, help, subparser)``.
    """
    actions, subcommands = [], []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help for a in action._choices_actions}
            names: dict[int, list[str]] = {}
            for name, sub in action.choices.items():
                names.setdefault(id(sub), []).append(name)
            for name, sub in action.choices.items():
                if names[id(sub)][0] == name:
                    subcommands.append((name, names[id(sub)][1:], helps.get(name), sub))
        else:
            actions.append(action)
    groups = [[a for a in g._group_actions] for g in parser._mutually_exclusive_groups]
    return actions, groups, subcommands


# ------------------------------------------------------------------ formatting
def _md(text: str) -> str:
    """Plain help text -> Markdown that shows it as written (no emphasis, links, maths or table
    breaks); an RST-style double-backquoted literal becomes a code span."""
    parts = re.split(r"``(.+?)``", " ".join(str(text).split()))
    return "".join(_code(p) if i % 2 else _escape(p) for i, p in enumerate(parts))


def _escape(text: str) -> str:
    text = html.escape(text, quote=False)
    text = re.sub(r"([\\`*_\[\]])", r"\\\1", text)
    return text.replace("|", "&#124;").replace("$", "&#36;")


def _code(text: str) -> str:
    """``text`` as an inline code span (a ``|`` in it does not split a table cell)."""
    text = str(text)
    fence = "``" if "`" in text else "`"
    pad = " " if text.startswith("`") or text.endswith("`") else ""
    return f"{fence}{pad}{text}{pad}{fence}"


def _metavar(action: argparse.Action) -> str:
    if action.metavar is not None:
        m = action.metavar if isinstance(action.metavar, str) else " ".join(action.metavar)
    elif action.choices is not None and not action.option_strings:
        m = "{" + ",".join(map(str, action.choices)) + "}"
    else:
        m = action.dest.upper() if action.option_strings else action.dest
    n = action.nargs
    if n is None:
        return m
    if n == argparse.OPTIONAL:
        return f"[{m}]"
    if n == argparse.ZERO_OR_MORE:
        return f"[{m} ...]"
    if n == argparse.ONE_OR_MORE:
        return f"{m} [{m} ...]"
    if isinstance(n, int):
        return " ".join([m] * n)
    return m


def _signature(action: argparse.Action) -> str:
    if not action.option_strings:
        return _metavar(action)
    if action.nargs == 0:
        return ", ".join(action.option_strings)
    return ", ".join(f"{o} {_metavar(action)}" for o in action.option_strings)


def _help(action: argparse.Action, prog: str) -> str:
    """The help as ``--help`` prints it (``%(default)s`` etc. filled in), minus a trailing
    ``(default: %(default)s)``, which the Default column shows."""
    text = action.help or ""
    if text == argparse.SUPPRESS:
        return ""
    text = re.sub(r"\s*\(default: %\(default\)s\)\s*$", "", text)
    params = dict(vars(action), prog=prog)
    params = {k: v for k, v in params.items() if v is not argparse.SUPPRESS}
    for k, v in list(params.items()):
        if hasattr(v, "__name__"):
            params[k] = v.__name__
    if params.get("choices") is not None:
        params["choices"] = ", ".join(map(str, params["choices"]))
    try:
        text = text % params
    except (KeyError, TypeError, ValueError):
        pass
    return text


def _default(action: argparse.Action) -> str:
    d = action.default
    if action.nargs == 0 or d is None or d is argparse.SUPPRESS or d == [] or not action.option_strings:
        return ""
    return _code(d)


def _usage(parser: argparse.ArgumentParser) -> str:
    """``parser.format_usage()`` at a fixed width (not the terminal's)."""
    old = parser.formatter_class
    parser.formatter_class = functools.partial(old, width=USAGE_WIDTH)
    try:
        return parser.format_usage().strip()
    finally:
        parser.formatter_class = old


def _sentence(desc: str, more: str) -> str:
    desc = desc.strip()
    if desc and desc[-1] not in ".!?:;":
        desc += "."
    return f"{desc} {more}".strip()


def _arguments_table(actions, groups) -> list[str]:
    exclusive = {id(a): [b for b in g if b is not a] for g in groups for a in g}
    rows = ["| Argument | Description | Default |", "| --- | --- | --- |"]
    for a in actions:
        if a.help == argparse.SUPPRESS:
            continue
        desc = _md(_help(a, ""))
        if a.choices is not None:
            desc = _sentence(desc, "Choices: " + ", ".join(_code(c) for c in a.choices) + ".")
        others = exclusive.get(id(a))
        if others:
            desc = _sentence(desc, "Not together with " + ", ".join(
                _code(o.option_strings[0] if o.option_strings else o.dest) for o in others) + ".")
        if not a.option_strings and a.nargs in (argparse.OPTIONAL, argparse.ZERO_OR_MORE):
            desc = "(optional) " + desc
        rows.append(f"| {_code(_signature(a))} | {desc.strip()} | {_default(a)} |")
    return rows


def _anchor(path: list[str]) -> str:
    return "-".join(path[1:]) or "top"


def _section(parser, path: list[str], level: int, out: list[str]) -> None:
    actions, groups, subs = parser_parts(parser)
    title = " ".join(path)
    out += [f"{'#' * level} `{title}` {{ #{_anchor(path)} }}", ""]
    if parser.description:
        out += [_md(parser.description), ""]
    out += ["```text", _usage(parser), "```", ""]
    positionals = [a for a in actions if not a.option_strings]
    options = [a for a in actions if a.option_strings]
    if positionals:
        out += ["**Arguments**", ""] + _arguments_table(positionals, groups) + [""]
    if options:
        out += ["**Options**", ""] + _arguments_table(options, groups) + [""]
    if subs:
        out += ["**Commands**", "", "| Command | What it does |", "| --- | --- |"]
        for name, aliases, help_, _ in subs:
            label = f"[{_code(name)}](#{_anchor(path + [name])})"
            if aliases:
                label += " (" + ", ".join(_code(x) for x in aliases) + ")"
            out.append(f"| {label} | {_md(help_ or '')} |")
        out.append("")
        for name, _, _, sub in subs:
            _section(sub, path + [name], level + 1, out)


def render_cli_reference(parser: argparse.ArgumentParser | None = None, level: int = 2) -> str:
    """Markdown for ``parser`` and, recursively, every subcommand: description, usage, and a
    table of every argument with its help, choices and default. ``parser`` defaults to
    ``bayes_brdf.cli.main.build_parser()``; headings start at ``level``."""
    if parser is None:
        from bayes_brdf.cli.main import build_parser

        parser = build_parser()
    out: list[str] = []
    _section(parser, [parser.prog], level, out)
    return "\n".join(out).rstrip() + "\n"


# ------------------------------------------------------------------ mkdocs events
def on_page_markdown(markdown, page, config, files, **kwargs):
    if MARKER in markdown:
        return markdown.replace(MARKER, render_cli_reference())
    if page.file.src_uri == PAGE:
        log.warning("%s: no '%s' marker; the CLI reference was not generated", PAGE, MARKER)
    return markdown

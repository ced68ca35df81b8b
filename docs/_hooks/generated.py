"""MkDocs hook: reference tables generated at build time from the code itself, so that the pages
can never disagree with it.

* ``<!-- scene-keys -->``: every key of a scene file, from the scene format's own JSON Schema
  (``teleop.scenario.schema.scene_schema``, what ``teleop schema`` prints);
* ``<!-- cli-help -->``: ``teleop --help`` and every subcommand's ``--help``, from the command's own
  parser (``teleop.app.cli.build_parser``);
* ``<!-- readme-python-api -->``: the README's Python API example, the block
  ``tests/integration/test_python_api.py`` runs, taken from the README the same way the test takes it.
"""

from __future__ import annotations

import re

MARKER = "<!-- scene-keys -->"
CLI_MARKER = "<!-- cli-help -->"
API_MARKER = "<!-- readme-python-api -->"


def _kind(s: dict) -> str:
    """A short description of a value's type and bounds."""
    if "anyOf" in s:
        return " or ".join(dict.fromkeys(_kind(o) for o in s["anyOf"]))
    if "enum" in s:
        return "one of " + ", ".join(f"`{v!r}`".replace("'", '"') for v in s["enum"])
    t = s.get("type", "")
    if t == "array":
        n = ""
        if "minItems" in s and s.get("minItems") == s.get("maxItems"):
            n = f"{s['minItems']} "
        elif "minItems" in s or "maxItems" in s:
            n = f"{s.get('minItems', 0)}-{s.get('maxItems', '…')} "
        if "prefixItems" in s:
            return f"array [{', '.join(_kind(i) for i in s['prefixItems'])}]"
        item = s.get("items", {})
        if item.get("type") == "object":
            return f"array of {n}tables"
        return f"array of {n}{_kind(item)}"
    bounds = []
    for word, sym in (("minimum", "≥"), ("exclusiveMinimum", ">"), ("maximum", "≤"), ("exclusiveMaximum", "<")):
        if word in s:
            bounds.append(f"{sym} {s[word]:g}")
    if t == "object":
        return "table"
    return t + (f" ({', '.join(bounds)})" if bounds else "")


def _plain(text) -> str:
    """A schema description as one line of Markdown: reST roles and double backticks made plain."""
    text = re.sub(r":[a-z]+:`~?([^`]+)`", r"`\1`", " ".join(str(text).split()))
    return text.replace("``", "`").replace("|", "\\|")


def _rows(prefix: str, s: dict, out: list) -> None:
    """One row per key, tables and arrays of tables descended into."""
    if "anyOf" in s and all(o.get("type") == "object" for o in s["anyOf"]):
        for o in s["anyOf"]:
            _rows(prefix, o, out)
        return
    for key, sub in s.get("properties", {}).items():
        path = f"{prefix}.{key}" if prefix else key
        desc = _plain(sub.get("description", ""))
        if sub.get("type") == "object" and "properties" in sub:
            out.append((f"`[{path}]`", "table", desc))
            _rows(path, sub, out)
        elif sub.get("type") == "array" and sub.get("items", {}).get("type") == "object":
            out.append((f"`[[{path}]]`", "array of tables", desc))
            _rows(path, sub["items"], out)
        elif "anyOf" in sub and all(o.get("type") == "object" for o in sub["anyOf"]):
            out.append((f"`[{path}]`", "table", desc))
            _rows(path, sub, out)
        else:
            out.append((f"`{path}`", _kind(sub), desc))


def scene_key_table() -> str:
    from teleop.scenario.schema import scene_schema

    rows: list = []
    _rows("", scene_schema(), rows)
    seen, lines = set(), ["| key | value | meaning |", "|---|---|---|"]
    for r in rows:
        if r not in seen:
            seen.add(r)
            lines.append("| " + " | ".join(r) + " |")
    return "\n".join(lines)


def cli_help() -> str:
    """Each command's help as printed, under a heading of its own."""
    import argparse
    import os

    from teleop.app.cli import build_parser

    os.environ["COLUMNS"] = "100"  # argparse wraps to the terminal; a fixed width for the page
    ap = build_parser()
    sub = next(a for a in ap._actions if isinstance(a, argparse._SubParsersAction))
    parts = ["### `teleop`", "", "```text", ap.format_help().rstrip(), "```", ""]
    for name, parser in sub.choices.items():
        parts += [f"### `teleop {name}`", "", "```text", parser.format_help().rstrip(), "```", ""]
    return "\n".join(parts)


def readme_python_api(config) -> str:
    """The first ```python block after the README's "## Python API" heading, fenced again."""
    from pathlib import Path

    text = (Path(config["config_file_path"]).parent / "README.md").read_text()
    section = text[text.index("## Python API"):]
    return "```python\n" + re.search(r"```python\n(.*?)```", section, re.S).group(1) + "```"


def on_page_markdown(markdown: str, page, config, files) -> str:
    if MARKER in markdown:
        markdown = markdown.replace(MARKER, scene_key_table())
    if API_MARKER in markdown:
        markdown = markdown.replace(API_MARKER, readme_python_api(config))
    if CLI_MARKER in markdown:
        markdown = markdown.replace(CLI_MARKER, cli_help())
    return markdown

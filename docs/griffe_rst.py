"""A Griffe extension for the API pages: the few reStructuredText habits of homofac's docstrings, as Markdown.

homofac's docstrings are Google-style (``Args:``, ``Returns:``, ``Raises:``, ``Attributes:``) with some
reStructuredText inside: roles such as ``:func:`x``` and ``:mod:`~a.b```, simple tables between
``=====`` rules, and literal blocks introduced by ``::``. mkdocstrings renders docstrings as Markdown,
where those read as noise (a rule under a line even becomes a heading). This extension rewrites them
while Griffe loads the package (the sources are not touched):

* a role ``:kind:`target``` becomes the code span ``target`` (``~a.b.c`` becomes ``c``);
* a simple table becomes a Markdown table;
* a paragraph ending in ``::`` ends in ``:`` (the indented block after it is code in Markdown too);
* an attribute documented by ``#:`` comment lines above it (Sphinx's doc comments) gets them as its
  docstring.

Registered in mkdocs.yml (``plugins.mkdocstrings.handlers.python.options.extensions``).
"""

from __future__ import annotations

import functools
import re
from pathlib import Path

import griffe

ROLE = re.compile(r":(?:py:)?(?:func|class|mod|meth|attr|data|obj|exc|const|ref|term):`(~?)([^`]+)`")
RULE = re.compile(r"^(\s*)(=+)((?: +=+)+)\s*$")


def escape_pipes(text: str) -> str:
    """``|`` escaped for a Markdown table cell, except inside code spans (the tables extension keeps those)."""
    parts = re.split(r"(`+[^`]*`+)", text)
    return "".join(p if p.startswith("`") else p.replace("|", "\\|") for p in parts)


def _role(m: re.Match) -> str:
    short, target = m.group(1), m.group(2).strip()
    if "<" in target and target.endswith(">"):  # :ref:`title <target>`
        target = target.split("<", 1)[0].strip()
    if short:
        target = target.rsplit(".", 1)[-1]
    return f"`{target}`"


def _columns(rule: str) -> list[tuple[int, int]]:
    return [(m.start(), m.end()) for m in re.finditer(r"=+", rule)]


def _cells(line: str, cols: list[tuple[int, int]]) -> list[str]:
    out = []
    for i, (start, _) in enumerate(cols):
        end = cols[i + 1][0] if i + 1 < len(cols) else len(line)
        out.append(escape_pipes(line[start:end].strip()))
    return out


def tables(text: str) -> str:
    """RST simple tables (rule, header, rule, rows, rule) as Markdown pipe tables."""
    lines = text.split("\n")
    out: list[str] = []
    i = 0
    while i < len(lines):
        m = RULE.match(lines[i])
        if not m:
            out.append(lines[i])
            i += 1
            continue
        indent = m.group(1)
        cols = _columns(lines[i])
        rules = [i]
        j = i + 1
        while j < len(lines) and len(rules) < 3:
            if RULE.match(lines[j]):
                rules.append(j)
            elif not lines[j].strip():
                break
            j += 1
        if len(rules) < 2:
            out.append(lines[i])
            i += 1
            continue
        if len(rules) == 2:  # a table without a header row
            header, body = None, lines[rules[0] + 1 : rules[1]]
        else:
            header, body = lines[rules[0] + 1 : rules[1]], lines[rules[1] + 1 : rules[2]]
        head = _cells(" ".join(header), cols) if header else [""] * len(cols)
        if out and out[-1].strip():
            out.append("")
        out.append(indent + "| " + " | ".join(head) + " |")
        out.append(indent + "|" + "|".join("---" for _ in cols) + "|")
        for row in body:
            if row.strip():
                out.append(indent + "| " + " | ".join(_cells(row, cols)) + " |")
        out.append("")
        i = rules[-1] + 1
    return "\n".join(out)


def literal_blocks(text: str) -> str:
    """``text::`` before an indented block becomes ``text:``; a line that is only ``::`` disappears."""
    out = []
    for line in text.split("\n"):
        stripped = line.rstrip()
        if stripped.strip() == "::":
            continue
        if stripped.endswith("::") and not stripped.endswith(":::"):
            line = stripped[:-1]
        out.append(line)
    return "\n".join(out)


def convert(text: str) -> str:
    """All rewrites of this extension (see the module docstring)."""
    return literal_blocks(tables(ROLE.sub(_role, text)))


@functools.lru_cache(maxsize=256)
def _lines(path: str) -> tuple[str, ...]:
    return tuple(Path(path).read_text().splitlines())


def doc_comment(obj: griffe.Object) -> str | None:
    """The ``#:`` comment lines right above an attribute's first line, as text (None when there are none)."""
    try:
        path, lineno = obj.filepath, obj.lineno
    except Exception:  # noqa: BLE001 - objects without a source file
        return None
    if not lineno or not isinstance(path, Path) or not path.is_file():
        return None
    lines = _lines(str(path))
    found = []
    i = lineno - 2
    while i >= 0 and lines[i].strip().startswith("#:"):
        found.append(lines[i].strip()[2:].strip())
        i -= 1
    return "\n".join(reversed(found)) or None


class RstToMarkdown(griffe.Extension):
    """Rewrite the reStructuredText habits of docstrings as Markdown when an object is loaded."""

    def on_instance(self, *, obj: griffe.Object, **kwargs) -> None:  # noqa: D102
        if obj.docstring is None and obj.is_attribute:
            text = doc_comment(obj)
            if text:
                obj.docstring = griffe.Docstring(text, parent=obj)
        if obj.docstring is not None and obj.docstring.value:
            obj.docstring.value = convert(obj.docstring.value)

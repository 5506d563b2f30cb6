"""Docstrings in the API pages: the Markdown ones, and the ones inherited from Gymnasium.

The envs' docstrings follow Gymnasium's: Markdown with ``## Description``,
``## Action Space``... headings and pipe tables. Autodoc reads every docstring
as reStructuredText, where those are not headings and the tables are line
blocks. A docstring with a Markdown heading is therefore handed to MyST
instead (the ``markdown-docstring`` directive below), its headings written as
rubrics: headings inside a class's description would become sections of the
page's table of contents.

A method that overrides one of Gymnasium's without a docstring of its own
(``SeifExploreEnv.step``) would show Gymnasium's, written in another style
(Google sections, Markdown); the page points to Gymnasium's method instead.
"""

from __future__ import annotations

import importlib
import re
from typing import Any

from docutils import nodes
from docutils.parsers.rst import Directive
from docutils.utils import new_document
from myst_parser.parsers.sphinx_ import MystParser
from sphinx.application import Sphinx

MARKDOWN_HEADING = re.compile(r"^(#{1,6})\s+(.+?)\s*#*\s*$")


def is_markdown(lines: list[str]) -> bool:
    """Whether a docstring's lines hold a Markdown heading (outside fenced code)."""
    fenced = False
    for line in lines:
        if line.lstrip().startswith("```"):
            fenced = not fenced
        elif not fenced and MARKDOWN_HEADING.match(line):
            return True
    return False


def headings_as_rubrics(lines: list[str]) -> list[str]:
    """The lines with every Markdown heading (outside fenced code) written as a MyST rubric."""
    out: list[str] = []
    fenced = False
    for line in lines:
        if line.lstrip().startswith("```"):
            fenced = not fenced
        match = None if fenced else MARKDOWN_HEADING.match(line)
        if match:
            out += ["", f"````{{rubric}} {match.group(2)}", "````", ""]
        else:
            out.append(line)
    return out


class MarkdownDocstring(Directive):
    """The directive's content parsed as MyST Markdown, in place."""

    has_content = True

    def run(self) -> list[nodes.Node]:
        text = "\n".join(headings_as_rubrics(list(self.content)))
        source = self.state.document.current_source or "<docstring>"
        document = new_document(source, self.state.document.settings)
        parser = MystParser()
        parser.parse(text, document)
        return list(document.children)


def inherited_from(obj: Any) -> str | None:
    """``module.Class.name`` of the method whose docstring ``obj`` (a method without one) inherits, or None."""
    if getattr(obj, "__doc__", "") is not None or not hasattr(obj, "__qualname__"):
        return None
    *owner_path, attr = obj.__qualname__.split(".")
    if not owner_path or "<locals>" in owner_path:
        return None
    try:
        owner: Any = importlib.import_module(obj.__module__)
        for part in owner_path:
            owner = getattr(owner, part)
    except (ImportError, AttributeError):
        return None
    for base in getattr(owner, "__mro__", ())[1:]:
        method = base.__dict__.get(attr)
        if method is not None and getattr(method, "__doc__", None):
            return f"{base.__module__}.{base.__qualname__}.{attr}"
    return None


def process_docstring(app: Sphinx, what: str, name: str, obj: Any, options: Any, lines: list[str]) -> None:
    if what in ("method", "function"):
        source = inherited_from(obj)
        if source is not None and not source.startswith(("seif_gym.", "agents.")):
            lines[:] = [f"Implements ``{source}``, whose documentation is that project's."]
            return
    if not is_markdown(lines):
        return
    wrapped = [".. markdown-docstring::", ""] + [f"   {line}" if line.strip() else "" for line in lines]
    lines[:] = wrapped


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_directive("markdown-docstring", MarkdownDocstring)
    # before napoleon (priority 500), which would read a Markdown table as text to reflow
    app.connect("autodoc-process-docstring", process_docstring, priority=100)
    return {"version": "1.0", "parallel_read_safe": True, "parallel_write_safe": True}

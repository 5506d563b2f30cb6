"""Toctree entries for pages that are still being written.

``pending_pages`` (conf.py) names pages the toctrees list before they exist.
While such a page is missing, its entry is dropped from every toctree when the
page that holds the toctree is read, so that the build stays free of warnings;
once the page exists it is in the site like any other. A page missing but not
listed there is a build error (``-W``), as Sphinx makes it: the list is the
only tolerance, and an empty list none.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from sphinx.application import Sphinx
from sphinx.util import logging

logger = logging.getLogger(__name__)
TOCTREE = re.compile(r"^(?P<fence>`{3,}|:{3,})\{toctree\}.*?^(?P=fence)\s*$", re.MULTILINE | re.DOTALL)


def missing_pending(app: Sphinx) -> set[str]:
    """The pending pages that have no source file yet."""
    srcdir = Path(app.srcdir)
    return {
        name
        for name in app.config.pending_pages
        if not any((srcdir / f"{name}{suffix}").is_file() for suffix in app.config.source_suffix)
    }


def drop_missing(app: Sphinx, docname: str, source: list[str]) -> None:
    missing = missing_pending(app)
    if not missing:
        return
    base = Path(docname).parent

    def entry_missing(line: str) -> bool:
        target = line.strip()
        if not target or target.startswith(":"):
            return False
        target = target.rsplit("<", 1)[-1].rstrip(">").strip()  # "Title <page>" entries
        name = target[1:] if target.startswith("/") else str(base / target) if str(base) != "." else target
        return str(Path(name)) in missing

    dropped: set[str] = set()

    def strip(match: re.Match[str]) -> str:
        kept = []
        for line in match.group(0).split("\n"):
            if entry_missing(line):
                dropped.add(line.strip())
            else:
                kept.append(line)
        return "\n".join(kept)

    source[0] = TOCTREE.sub(strip, source[0])
    if dropped:
        dropped_entries(app.env)[docname] = missing


def dropped_entries(env: Any) -> dict[str, set[str]]:
    """The pending pages that were missing when each page (the key) was read (kept in the environment between builds)."""
    if not hasattr(env, "pending_pages_missing"):
        env.pending_pages_missing = {}
    return env.pending_pages_missing


def outdated(app: Sphinx, env: Any, added: set[str], changed: set[str], removed: set[str]) -> list[str]:
    """The pages whose toctrees dropped a page that exists now: read again, so that it is listed."""
    missing = missing_pending(app)
    return [doc for doc, was_missing in dropped_entries(env).items() if was_missing - missing]


def purge(app: Sphinx, env: Any, docname: str) -> None:
    dropped_entries(env).pop(docname, None)


def merge(app: Sphinx, env: Any, docnames: set[str], other: Any) -> None:
    dropped_entries(env).update({doc: dropped_entries(other)[doc] for doc in docnames if doc in dropped_entries(other)})


def report(app: Sphinx, exception: Exception | None) -> None:
    missing = sorted(missing_pending(app))
    if missing and exception is None:
        logger.info("pages in the toctrees still to be written: %s", ", ".join(missing))


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_config_value("pending_pages", [], "env", types=[list])
    app.connect("source-read", drop_missing)
    app.connect("env-get-outdated", outdated)
    app.connect("env-purge-doc", purge)
    app.connect("env-merge-info", merge)
    app.connect("build-finished", report)
    return {"version": "1.0", "parallel_read_safe": True, "parallel_write_safe": True}

"""Sphinx configuration of the seif_gym documentation site.

Build it with::

    pip install -e ".[docs]"
    sphinx-build -W --keep-going -b html docs docs/_build/html

The stack is the one of the Farama Foundation's sites (Gymnasium's among them):
Sphinx, MyST for the Markdown pages and the Furo theme. The task pages
(``docs/tasks/``) and the leaderboards (``docs/benchmark/leaderboard*.md``) are
written at build time by the extensions in ``docs/_ext/`` and are not kept in
git.
"""

from __future__ import annotations

import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
# the package is imported from the checkout, installed or not, so that the API pages are the code's
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(DOCS / "_ext"))

import seif_gym  # noqa: E402

project = "seif_gym"
author = "the seif_gym authors"
copyright = "the seif_gym authors, MIT licence"  # noqa: A001
release = seif_gym.__version__
version = ".".join(release.split(".")[:2])

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
    # math as MathML written at build time (no script from a CDN: the pages work offline)
    "mathml",
    # Markdown docstrings (the envs') and those inherited from Gymnasium, in the API pages
    "docstrings",
    # docs/tasks/*.md from the gymnasium registry, docs/benchmark/leaderboard*.md from the json files
    "task_pages",
    "leaderboard_pages",
    # the toctree's pages that other pages are still being written for
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = [
    "_build",
    "Thumbs.db",
    ".DS_Store",
    # prose included into the generated leaderboards, not pages of their own
    "benchmark/*_intro.md",
    "benchmark/*_after.md",
    # GIF cache of the task pages
    "tasks/_gifs",
]
templates_path = ["_templates"]
html_static_path = ["_static"]

# -- MyST ------------------------------------------------------------------------------------------
myst_enable_extensions = ["amsmath", "colon_fence", "deflist", "dollarmath", "fieldlist", "attrs_inline"]
# GitHub's anchors for headings down to ###, so that a page's `other.md#a-heading` links work here too
myst_heading_anchors = 3

# -- API pages -------------------------------------------------------------------------------------
autodoc_default_options = {"members": True, "show-inheritance": True, "member-order": "bysource"}
autodoc_typehints = "signature"
autodoc_preserve_defaults = True
autodoc_class_signature = "separated"
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False
napoleon_use_ivar = True

# -- generated pages -------------------------------------------------------------------------------
# docs/_ext/leaderboard_pages.py: each run's json (what `python -m agents.benchmark` writes) -> its page
leaderboard_pages = [
    {"json": "leaderboard.json", "page": "benchmark/leaderboard.md", "intro": "benchmark/leaderboard_intro.md"},
    {
        "json": "leaderboard_v1.json",
        "page": "benchmark/leaderboard_v1.md",
        "intro": "benchmark/leaderboard_v1_intro.md",
        "after": "benchmark/leaderboard_v1_after.md",
    },
]

# -- math ------------------------------------------------------------------------------------------
html_math_renderer = "mathml"

# -- HTML ------------------------------------------------------------------------------------------
html_theme = "furo"
html_title = "seif_gym"
html_short_title = "seif_gym"
# a favicon of our own, so that browsers do not ask the server for /favicon.ico (a 404 in the console)
html_favicon = "_static/favicon.svg"
html_css_files = ["custom.css"]
html_show_sourcelink = False
html_copy_source = False
html_theme_options = {
    "source_repository": "",
    "navigation_with_keys": True,
}

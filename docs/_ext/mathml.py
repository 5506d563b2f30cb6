"""Math written as MathML at build time, so that the pages need no script and no network.

Sphinx's own renderers are MathJax (a script from a CDN: offline, a reader's
browser logs a failed load and shows the LaTeX source) and imgmath (LaTeX and
dvipng on the build machine). Browsers render MathML Core natively, and
docutils converts LaTeX to it (``docutils.utils.math.latex2mathml``), so this
renderer writes the MathML into the page. A formula docutils cannot convert is
a build warning (``-W`` makes it an error) and is shown as its LaTeX source.
"""

from __future__ import annotations

import re
from typing import Any

from docutils import nodes
from docutils.utils.math import latex2mathml
from sphinx.application import Sphinx
from sphinx.locale import _
from sphinx.util import logging
from sphinx.util.math import get_node_equation_number
from sphinx.writers.html5 import HTML5Translator

logger = logging.getLogger(__name__)
# TeX's spacing classes, which docutils does not know: the braced argument is kept as it is
SPACING_CLASSES = re.compile(r"\\math(?:rel|bin|ord|open|close|punct)(?=\s*\{)")
# amsmath's commands that docutils lacks -> the ones it has
SYNONYMS = [(re.compile(r"\\dots(?![a-zA-Z])"), r"\\ldots")]


def supported(latex: str) -> str:
    """``latex`` with the commands docutils does not know replaced by equivalents it knows."""
    latex = SPACING_CLASSES.sub("", latex)
    for pattern, replacement in SYNONYMS:
        latex = pattern.sub(replacement, latex)
    return latex


def to_mathml(latex: str, node: nodes.Node, block: bool) -> str | None:
    """The MathML of ``latex``, or None (and a warning at ``node``) where docutils cannot convert it."""
    try:
        return latex2mathml.tex2mathml(supported(latex), as_block=block)
    except Exception as error:  # docutils raises SyntaxError, and others, on unsupported LaTeX
        logger.warning("cannot write this formula as MathML (%s): %s", error, latex, location=node, type="mathml")
        return None


def visit_math(self: HTML5Translator, node: nodes.math) -> None:
    latex = node.astext()
    mathml = to_mathml(latex, node, block=False)
    self.body.append(self.starttag(node, "span", "", CLASS="math notranslate"))
    self.body.append(mathml if mathml is not None else f"<code>{self.encode(latex)}</code>")
    self.body.append("</span>")
    raise nodes.SkipNode


def visit_displaymath(self: HTML5Translator, node: nodes.math_block) -> None:
    latex = node.astext()
    parts = [part for part in latex.split("\n\n") if part.strip()]
    if len(parts) > 1:
        # equations separated by blank lines, as Sphinx's math directive allows: one aligned block
        latex = r"\begin{aligned}" + r"\\".join(parts) + r"\end{aligned}"
    self.body.append(self.starttag(node, "div", CLASS="math notranslate"))
    if node.get("number"):
        number = get_node_equation_number(self, node)
        self.body.append(f'<span class="eqno">({number})')
        self.add_permalink_ref(node, _("Link to this equation"))
        self.body.append("</span>")
    mathml = to_mathml(latex, node, block=True)
    self.body.append(mathml if mathml is not None else f"<pre>{self.encode(latex)}</pre>")
    self.body.append("</div>\n")
    raise nodes.SkipNode


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_html_math_renderer("mathml", inline_renderers=(visit_math, None), block_renderers=(visit_displaymath, None))
    return {"version": "1.0", "parallel_read_safe": True, "parallel_write_safe": True}

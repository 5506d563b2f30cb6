"""Every relative link of the README and the docs points at a file that exists, and at a heading it has.

Documents are moved and split (the protocol's recipes now live in the research
log); a link left behind fails here, not in a reader's browser. This test
needs no build: the site's own test (tests/docs/test_site.py) checks the built
pages in a browser.

* README.md may link any file of the repository; a docs page only pages and
  files under docs/, since the site is built from docs/ alone. Nothing links
  outside the repository.
* Anchors follow GitHub's rule (the heading lowercased, every character but
  letters, digits, spaces, hyphens and underscores dropped, spaces made
  hyphens), which MyST follows too for headings of levels 1 to 3 (conf.py's
  ``myst_heading_anchors``): a docs page's link may only name those.
* ``{doc}`` roles name a page of the site: a Markdown file under docs/, or one
  the build writes (the task pages, the leaderboards).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
#: Pages the build writes (docs/_ext/): gitignored, so not checked as sources, but valid link targets.
GENERATED = ("tasks", "benchmark/leaderboard", "benchmark/leaderboard_v1")
#: Heading levels MyST gives an anchor (conf.py's myst_heading_anchors).
ANCHOR_LEVELS = 3


def generated(path: Path) -> bool:
    name = path.relative_to(DOCS).with_suffix("").as_posix()
    return any(name == g or name.startswith(g + "/") for g in GENERATED)


def sources() -> list[Path]:
    docs = [p for p in sorted(DOCS.rglob("*.md")) if "_build" not in p.relative_to(DOCS).parts and not generated(p)]
    return [ROOT / "README.md", *docs]


DOCUMENTS = sources()
LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)|!\[[^\]]*\]\(([^)\s]+)\)")
DOC_ROLE = re.compile(r"\{doc\}`([^`]+)`")
FENCE_OPEN = re.compile(r"^\s*(`{3,}|~{3,})\s*(\{([\w-]+)\})?")
#: Directives whose body is code or math, not prose: left out like plain fenced code.
VERBATIM = {"code", "code-block", "code-cell", "math", "eval-rst", "toctree", "literalinclude"}
INLINE_CODE = re.compile(r"(?<!`)`[^`\n]+`(?!`)")


def github_anchor(heading: str) -> str:
    """The fragment GitHub gives a Markdown heading."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def prose(path: Path) -> str:
    """The text outside fenced code and math (the body of a prose directive, ```{note}, is kept)."""
    kept: list[str] = []
    fences: list[tuple[str, bool]] = []  # the open fences: (marker, verbatim)
    for line in path.read_text(encoding="utf-8").splitlines():
        match = FENCE_OPEN.match(line)
        if fences and match and match.group(1)[0] == fences[-1][0][0] and len(match.group(1)) >= len(fences[-1][0]):
            if not match.group(2) and not line.strip()[len(match.group(1)) :].strip():
                fences.pop()  # a closing fence
                continue
        if match and not (fences and fences[-1][1]):
            directive = match.group(3)
            fences.append((match.group(1), directive is None or directive in VERBATIM))
            continue
        if not any(verbatim for _, verbatim in fences):
            kept.append(line)
    return "\n".join(kept)


def anchors(path: Path, max_level: int = 6) -> set[str]:
    pattern = rf"^#{{1,{max_level}}}\s+(.+?)\s*#*\s*$"
    return {github_anchor(m.group(1)) for m in re.finditer(pattern, prose(path), re.MULTILINE)}


def relative_links(path: Path) -> list[str]:
    text = INLINE_CODE.sub("", prose(path))
    targets = [a or b for a, b in LINK.findall(text)]
    return [t for t in targets if not re.match(r"^[a-z][a-z0-9+.-]*:", t)]


def doc_roles(path: Path) -> list[str]:
    return [m.group(1).rsplit("<", 1)[-1].rstrip(">").strip() for m in DOC_ROLE.finditer(prose(path))]


def test_github_anchor() -> None:
    assert github_anchor("Shipped policies") == "shipped-policies"
    assert (
        github_anchor("The adversary against the faithful SEIF (-v1, issue 15 point 5)")
        == "the-adversary-against-the-faithful-seif--v1-issue-15-point-5"
    )


def test_documents_cover_the_docs() -> None:
    names = {p.relative_to(ROOT).as_posix() for p in DOCUMENTS}
    assert "README.md" in names and "docs/index.md" in names
    assert all(not n.startswith("docs/tasks/") for n in names)


def page_exists(target: Path) -> bool:
    """A docs page exists as a source, or is one the build writes."""
    return target.is_file() or (target.suffix == ".md" and target.is_relative_to(DOCS) and generated(target))


@pytest.mark.parametrize("document", DOCUMENTS, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(document: Path) -> None:
    in_docs = document.is_relative_to(DOCS)
    broken = []
    for target in relative_links(document):
        file_part, _, fragment = target.partition("#")
        linked = (document.parent / file_part).resolve() if file_part else document
        if not linked.is_relative_to(ROOT):
            broken.append(f"{target}: outside the repository")
        elif in_docs and not linked.is_relative_to(DOCS):
            broken.append(f"{target}: outside docs/, which the site is built from (name the file as code instead)")
        elif not page_exists(linked):
            broken.append(f"{target}: no such file")
        elif fragment and linked.suffix == ".md" and linked.is_file():
            levels = ANCHOR_LEVELS if in_docs else 6
            if fragment not in anchors(linked, levels):
                broken.append(
                    f"{target}: no heading #{fragment} (of level 1 to {levels}) in {linked.relative_to(ROOT)}"
                )
    assert not broken, f"{document.relative_to(ROOT)}: " + "; ".join(broken)


@pytest.mark.parametrize(
    "document", [d for d in DOCUMENTS if d.is_relative_to(DOCS)], ids=lambda p: str(p.relative_to(ROOT))
)
def test_doc_roles_name_pages(document: Path) -> None:
    missing = []
    for target in doc_roles(document):
        page = (DOCS / target.lstrip("/")) if target.startswith("/") else (document.parent / target)
        page = page.resolve().with_suffix(".md") if page.suffix != ".md" else page.resolve()
        if not page.is_relative_to(DOCS) or not page_exists(page):
            missing.append(target)
    assert not missing, f"{document.relative_to(ROOT)}: {{doc}} roles naming no page: {missing}"

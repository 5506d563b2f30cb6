"""One page per registered task, written at build time: ``docs/tasks/<id>.md`` and ``docs/tasks/index.md``.

As on Gymnasium's site, a task family (``SeifExploreLoop``) has one page, named
after its newest version (``SeifExploreLoop-v2.md``), whose version history
lists the older ids that stay registered. Everything on a page comes from the
code and the repository, so that the pages cannot drift from them:

* the ids, their keyword arguments and time limits: the Gymnasium registry
  after ``import seif_gym`` (every id whose entry point is in ``seif_gym``);
* the spaces: the env built with ``gym.make``;
* the description, action and observation spaces, reward, starting state,
  episode end, info and arguments: the Markdown sections (``## ...``) of
  ``SeifExploreEnv``'s docstring (for ``SeifExploreMRCLAM`` the description of
  ``seif_gym.envs.mrclam``'s);
* the layouts' descriptions: ``seif_gym.world.make_landmarks``'s docstring;
* the version history: the ``## Environment versions`` section of the
  repository's CHANGELOG.md;
* whether the task is on the leaderboard: ``docs/leaderboard.json``;
* a GIF of a short episode: ``render_mode="rgb_array"`` frames of a seeded
  episode driven by a fixed open-loop wander (no agent package is needed),
  cached in ``docs/tasks/_gifs/`` under a hash of the seif_gym version, the id
  and the settings, so that a rebuild renders nothing.

The folder is generated: every file in it is rewritten or removed here.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import pprint
import re
import textwrap
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sphinx.application import Sphinx
from sphinx.util import logging

logger = logging.getLogger(__name__)

#: Frames of each task's GIF, one every ``GIF_STRIDE`` steps of the episode, and their size and pace.
GIF_FRAMES = 40
GIF_STRIDE = 3
GIF_WIDTH = 400
GIF_FRAME_MS = 150
GIF_SEED = 0
#: The docstring's sections in the order of the page; "Version History" comes from the changelog.
SECTIONS = ("Description", "Action Space", "Observation Space", "Rewards", "Starting State", "Episode End", "Info")
CHANGELOG_SECTION = "Environment versions"


@dataclass(frozen=True)
class Version:
    env_id: str
    version: int
    kwargs: dict[str, Any]
    max_episode_steps: int | None


@dataclass(frozen=True)
class Family:
    name: str
    versions: tuple[Version, ...]  # oldest first

    @property
    def newest(self) -> Version:
        return self.versions[-1]


# -- reading the code and the repository ------------------------------------------------------------


def families() -> list[Family]:
    """Every task family registered by ``import seif_gym``, in registration order."""
    from gymnasium.envs.registration import registry

    import seif_gym  # noqa: F401  (registers the ids)

    grouped: dict[str, list[Version]] = {}
    for env_id, spec in registry.items():
        entry = spec.entry_point if isinstance(spec.entry_point, str) else getattr(spec.entry_point, "__module__", "")
        if not str(entry).startswith("seif_gym") or spec.namespace is not None:
            continue
        version = Version(env_id, spec.version or 0, dict(spec.kwargs), spec.max_episode_steps)
        grouped.setdefault(spec.name, []).append(version)
    return [Family(name, tuple(sorted(vs, key=lambda v: v.version))) for name, vs in grouped.items()]


def markdown_sections(doc: str | None) -> dict[str, str]:
    """``## Heading`` -> the Markdown under it, of a Gymnasium-style docstring (fenced code kept whole)."""
    sections: dict[str, list[str]] = {}
    current: list[str] | None = None
    fenced = False
    for line in textwrap.dedent(doc or "").splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
        match = None if fenced else re.match(r"^##\s+(.+?)\s*$", line)
        if match:
            current = sections.setdefault(match.group(1).strip(), [])
        elif current is not None:
            current.append(line)
    return {name: "\n".join(lines).strip() for name, lines in sections.items()}


def docstring_of(obj: Any) -> str:
    """``obj.__doc__`` with its first line kept apart from the indented rest, dedented."""
    doc = obj.__doc__ or ""
    first, _, rest = doc.partition("\n")
    return first.strip() + "\n" + textwrap.dedent(rest)


def layout_descriptions() -> dict[str, str]:
    """Layout name -> its description, from the bullets of ``seif_gym.world.make_landmarks``'s docstring."""
    from seif_gym.world import make_landmarks

    text = textwrap.dedent(docstring_of(make_landmarks))
    found = {}
    for match in re.finditer(r'^\*\s+``"(\w+)"``:\s+(.+?)(?=^\*|^\s*$)', text, re.MULTILINE | re.DOTALL):
        found[match.group(1)] = " ".join(match.group(2).split()).replace("``", "`")
    return found


def changelog_bullets(root: Path) -> list[str] | None:
    """The bullets of CHANGELOG.md's ``## Environment versions`` section, or None without that section."""
    path = root / "CHANGELOG.md"
    if not path.is_file():
        return None
    bullets: list[str] = []
    inside = False
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("## "):
            inside = line[3:].strip().lower() == CHANGELOG_SECTION.lower()
            continue
        if not inside:
            continue
        if line.startswith("- "):
            bullets.append(line)
        elif bullets and (line.startswith("  ") or not line.strip()) and not line.startswith("#"):
            bullets[-1] += "\n" + line
        elif line.startswith("#"):
            inside = False
    return [bullet.rstrip() for bullet in bullets] if inside or bullets else None


def bullets_for(family: Family, bullets: Iterable[str]) -> list[str]:
    """The changelog's bullets of a family: ``- **Name-vN**`` ones for it, ``- **-vN**`` ones for the others."""
    # the family's name followed by -v exactly: SeifExplore's own bullets are not SeifExploreMRCLAM's
    own = re.compile(rf"^- \*\*{re.escape(family.name)}-v\d+\*\*")
    shared = re.compile(r"^- \*\*-v\d+\*\*")
    mine = [b for b in bullets if own.match(b)]
    if mine or family.name.endswith("MRCLAM"):
        return mine
    return [b for b in bullets if shared.match(b)]


def rewrite_links(markdown: str, root: Path, page_dir: Path) -> str:
    """Relative links of the changelog (written from the repository root) made to work from ``page_dir``.

    A link into ``docs/`` becomes a link to that page; a link to any other file of the repository becomes
    its path as code: the site holds the docs, not the sources.
    """

    def fix(match: re.Match[str]) -> str:
        text, target = match.group(1), match.group(2)
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
            return match.group(0)
        path, _, anchor = target.partition("#")
        if path.startswith("docs/"):
            relative = Path(*([".."] * len(page_dir.parts))) / path[len("docs/") :]
            return f"[{text}]({relative.as_posix()}{'#' + anchor if anchor else ''})"
        return f"{text} (`{path}`)"

    return re.sub(r"(?<!!)\[([^\]]+)\]\(([^)\s]+)\)", fix, markdown)


# -- the GIF -----------------------------------------------------------------------------------------


def wander(step: int) -> list[float]:
    """The GIF's open-loop action: nearly full speed, the heading swinging slowly from side to side."""
    import math

    return [0.9, 0.7 * math.sin(step / 9.0)]


def gif_key(env_id: str) -> str:
    import seif_gym

    settings = (seif_gym.__version__, env_id, GIF_FRAMES, GIF_STRIDE, GIF_WIDTH, GIF_FRAME_MS, GIF_SEED, "wander-1")
    return hashlib.sha256(repr(settings).encode()).hexdigest()[:12]


def render_gif(env_id: str, path: Path) -> None:
    """Write the GIF of a seeded episode of ``env_id`` to ``path``."""
    import gymnasium as gym
    import numpy as np
    from PIL import Image

    import seif_gym  # noqa: F401  (registers the ids)

    env = gym.make(env_id, render_mode="rgb_array")
    try:
        env.reset(seed=GIF_SEED)
        frames = [env.render()]
        for step in range(GIF_FRAMES * GIF_STRIDE):
            _, _, terminated, truncated, _ = env.step(np.asarray(wander(step), dtype=np.float32))
            if (step + 1) % GIF_STRIDE == 0:
                frames.append(env.render())
            if terminated or truncated:
                break
    finally:
        env.close()
    images = []
    for frame in frames:
        image = Image.fromarray(np.asarray(frame))
        height = round(image.height * GIF_WIDTH / image.width)
        images.append(image.resize((GIF_WIDTH, height), Image.Resampling.LANCZOS).quantize(colors=64))
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(".partial.gif")
    images[0].save(
        partial, save_all=True, append_images=images[1:], duration=GIF_FRAME_MS, loop=0, optimize=True, disposal=1
    )
    partial.replace(path)


# -- the pages ---------------------------------------------------------------------------------------


def space_rows(space: Any) -> list[tuple[str, str, str, str, str]]:
    """(key, type, shape, dtype, bounds) of each part of a (Dict of) Box space."""
    import numpy as np

    parts = space.spaces.items() if hasattr(space, "spaces") and isinstance(space.spaces, dict) else [("", space)]
    rows = []
    for key, part in parts:
        low, high = getattr(part, "low", None), getattr(part, "high", None)
        if low is not None and high is not None:
            lo = np.unique(low)
            hi = np.unique(high)
            bounds = (
                f"[{lo[0]:g}, {hi[0]:g}]"
                if lo.size == 1 and hi.size == 1
                else f"[{lo.min():g}, {hi.max():g}] (per element)"
            )
        else:
            bounds = ""
        rows.append(
            (
                f"`{key}`" if key else "",
                type(part).__name__,
                str(getattr(part, "shape", "")),
                str(getattr(part, "dtype", "")),
                bounds,
            )
        )
    return rows


def table(header: Iterable[str], rows: Iterable[Iterable[str]]) -> str:
    header = list(header)
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(cell).replace("|", "\\|") for cell in row) + " |" for row in rows]
    return "\n".join(lines)


def defaults() -> dict[str, Any]:
    """``SeifExploreEnv``'s keyword arguments and their defaults."""
    from seif_gym.envs.explore import SeifExploreEnv

    parameters = inspect.signature(SeifExploreEnv.__init__).parameters.values()
    return {p.name: p.default for p in parameters if p.default is not inspect.Parameter.empty}


def world_of(version: Version) -> dict[str, Any]:
    """layout, landmarks, arena and steps of an id."""
    merged = {**defaults(), **version.kwargs}
    extent = merged.get("arena_extent")
    arena = f"{extent[0]:g} × {extent[1]:g} m" if extent else f"{merged['arena_size']:g} × {merged['arena_size']:g} m"
    return {
        "layout": merged["layout"],
        "landmarks": merged["num_landmarks"],
        "arena": arena,
        "steps": version.max_episode_steps,
    }


def differs(version: Version, newest: Version) -> str:
    """The keyword arguments in which an id differs from the family's newest, as code."""
    keys = sorted(set(version.kwargs) | set(newest.kwargs))
    changed = [k for k in keys if version.kwargs.get(k) != newest.kwargs.get(k)]
    if version.max_episode_steps != newest.max_episode_steps:
        changed.append("max_episode_steps")
    if not changed:
        return "—"
    values = {**version.kwargs, "max_episode_steps": version.max_episode_steps}
    return ", ".join(f"`{k}={values.get(k)!r}`" for k in changed)


def leaderboard_tasks(docs: Path) -> dict[str, int]:
    """Id -> held-out episodes per agent, of the tasks on the current leaderboard."""
    path = docs / "leaderboard.json"
    if not path.is_file():
        return {}
    return {str(k): int(v) for k, v in json.loads(path.read_text(encoding="utf-8")).get("episodes", {}).items()}


def family_page(
    family: Family,
    env_doc: dict[str, str],
    mrclam_doc: dict[str, str],
    layouts: dict[str, str],
    bullets: list[str] | None,
    on_leaderboard: dict[str, int],
    gif: str,
    root: Path,
) -> str:
    import gymnasium as gym

    newest = family.newest
    env = gym.make(newest.env_id)
    try:
        observation_space, action_space = env.observation_space, env.action_space
    finally:
        env.close()
    world = world_of(newest)
    steps = newest.max_episode_steps
    mrclam = family.name.endswith("MRCLAM")
    out = [
        f"# {newest.env_id}",
        "",
        f"```{{image}} {gif}",
        f":alt: An episode of {newest.env_id} (seed {GIF_SEED}, an open-loop wander): the true landmarks and path, "
        "the filter's estimates and their uncertainty, and the agent's belief-map observation",
        f":width: {GIF_WIDTH}px",
        "```",
        "",
        table(
            ["", ""],
            [
                ["Action space", f"`{action_space}`"],
                [
                    "Observation space",
                    "`Dict` of " + ", ".join(f"`{k}`" for k in getattr(observation_space, "spaces", {})),
                ],
                ["Episode length", f"{steps} steps (`max_episode_steps`)"],
                ["World", f"{world['layout']} layout, {world['landmarks']} landmarks, {world['arena']}"],
                ["Import", f'`gym.make("{newest.env_id}")` after `import seif_gym`'],
                ["Versions", ", ".join(f"`v{v.version}`" for v in reversed(family.versions))],
            ],
        ),
        "",
        f"*The GIF: {GIF_FRAMES} frames, one every {GIF_STRIDE} steps, of the episode of seed {GIF_SEED} driven by a "
        "fixed open-loop wander (not a trained agent).*",
        "",
        "## Description",
        "",
    ]
    if mrclam and mrclam_doc.get("Description"):
        out += [mrclam_doc["Description"], ""]
    else:
        layout = world["layout"]
        layout_text = layouts.get(layout)
        out += [
            f"Layout `{layout}`"
            + (f": {layout_text.rstrip('.')}." if layout_text else ".")
            + f" {world['landmarks']} landmarks in a {world['arena']} arena, {steps} steps per episode.",
            "",
        ]
        if steps is not None and steps < 400:
            out += [
                f"A step budget: {steps} steps do not leave time to map everything twice, so an agent has to "
                "choose what to map well and when to revisit (the benchmark protocol says why each budget was "
                "chosen: {doc}`../benchmark/protocol`).",
                "",
            ]
        out += [env_doc.get("Description", ""), ""]
    if newest.env_id in on_leaderboard:
        out += [
            f"A benchmark task: the leaderboard runs it on {on_leaderboard[newest.env_id]} held-out episodes per "
            "agent ({doc}`../benchmark/leaderboard`).",
            "",
        ]
    else:
        out += ["Not a benchmark task: no leaderboard run covers it.", ""]
    for name in SECTIONS[1:]:
        if name not in env_doc:
            continue
        out += [f"## {name}", "", env_doc[name], ""]
        if name == "Observation Space":
            out += [
                f"The spaces of `{newest.env_id}`, from the env:",
                "",
                table(["key", "space", "shape", "dtype", "bounds"], space_rows(observation_space)),
                "",
            ]
        if name == "Episode End":
            out += [f"For `{newest.env_id}` the time limit is **{steps} steps**.", ""]
    out += [
        "## Arguments",
        "",
        "```python",
        "import gymnasium as gym",
        "import seif_gym",
        "",
        f'env = gym.make("{newest.env_id}")',
        f'envs = gym.make_vec("{newest.env_id}", num_envs=8)  # 8 envs stepped together (SeifExploreVectorEnv)',
        "```",
        "",
        f"`{newest.env_id}` is `SeifExploreEnv` registered with these keyword arguments (the others take their "
        f"defaults) and `max_episode_steps={steps}`:",
        "",
        "```python",
        pprint.pformat(newest.kwargs, width=100, sort_dicts=False),
        "```",
        "",
        "Any argument can be changed at `gym.make`:",
        "",
        env_doc.get("Arguments", ""),
        "",
        "## Version History",
        "",
        "Every version stays registered, so that a result measured on it can be reproduced; a change that alters "
        "what an id computes gets a new version.",
        "",
        table(
            ["id", f"differs from {newest.env_id} in", "max_episode_steps"],
            [
                [f"`{v.env_id}`", differs(v, newest) if v is not newest else "(newest)", str(v.max_episode_steps)]
                for v in reversed(family.versions)
            ],
        ),
        "",
    ]
    if bullets is None:
        changelog = "{doc}`../changelog`" if (root / "docs" / "changelog.md").is_file() else "`CHANGELOG.md`"
        out += [f"For what changed in each version, see the changelog ({changelog}).", ""]
    else:
        mine = bullets_for(family, bullets)
        if mine:
            out += ["From the changelog:", ""]
            out += [rewrite_links(b, root, Path("tasks")) for b in mine]
            out += [""]
        else:
            out += ["The changelog has no entry for this family's versions yet.", ""]
    return "\n".join(out).rstrip() + "\n"


def index_page(all_families: list[Family], on_leaderboard: dict[str, int]) -> str:
    rows = []
    for family in all_families:
        newest = family.newest
        world = world_of(newest)
        older = ", ".join(f"`{v.env_id}`" for v in reversed(family.versions[:-1])) or "—"
        bench = f"yes ({on_leaderboard[newest.env_id]} episodes)" if newest.env_id in on_leaderboard else "no"
        rows.append(
            [
                f"[{newest.env_id}]({newest.env_id}.md)",
                world["layout"],
                str(world["landmarks"]),
                world["arena"],
                str(world["steps"]),
                bench,
                older,
            ]
        )
    toctree = ["```{toctree}", ":hidden:", ""] + [f.newest.env_id for f in all_families] + ["```"]
    return (
        "\n".join(
            [
                "# Tasks",
                "",
                "Every task is a registered Gymnasium id: `gym.make(id)` after `import seif_gym`. A task's page "
                "shows an episode, its spaces, reward, episode end, arguments and version history; the table "
                "lists each task at its newest version, with the older versions that stay registered.",
                "",
                table(
                    [
                        "task",
                        "layout",
                        "landmarks",
                        "arena",
                        "steps",
                        "on the leaderboard",
                        "older versions",
                    ],
                    rows,
                ),
                "",
                "These pages are written when the site is built, from the registry and the env's docstring "
                "(`docs/_ext/task_pages.py`).",
                "",
                *toctree,
            ]
        )
        + "\n"
    )


def write_if_changed(path: Path, text: str) -> None:
    if not path.is_file() or path.read_text(encoding="utf-8") != text:
        path.write_text(text, encoding="utf-8")


def write_task_pages(app: Sphinx) -> None:
    from seif_gym.envs import explore, mrclam

    docs = Path(app.srcdir)
    root = docs.parent
    folder = docs / "tasks"
    gifs = folder / "_gifs"
    folder.mkdir(exist_ok=True)
    all_families = families()
    env_doc = markdown_sections(docstring_of(explore.SeifExploreEnv))
    mrclam_doc = markdown_sections(docstring_of(mrclam))
    layouts = layout_descriptions()
    bullets = changelog_bullets(root)
    if bullets is None:
        logger.info("task pages: no '## %s' in CHANGELOG.md; the pages point to the changelog", CHANGELOG_SECTION)
    on_leaderboard = leaderboard_tasks(docs)
    wanted_pages = {"index.md"}
    wanted_gifs = set()
    for family in all_families:
        env_id = family.newest.env_id
        gif = gifs / f"{env_id}-{gif_key(env_id)}.gif"
        wanted_gifs.add(gif.name)
        if not gif.is_file():
            logger.info("task pages: rendering %s", gif.name)
            render_gif(env_id, gif)
        page = family_page(family, env_doc, mrclam_doc, layouts, bullets, on_leaderboard, f"_gifs/{gif.name}", root)
        write_if_changed(folder / f"{env_id}.md", page)
        wanted_pages.add(f"{env_id}.md")
    write_if_changed(folder / "index.md", index_page(all_families, on_leaderboard))
    for stale in folder.glob("*.md"):
        if stale.name not in wanted_pages:
            stale.unlink()
    for stale in gifs.glob("*.gif"):
        if stale.name not in wanted_gifs:
            stale.unlink()


def setup(app: Sphinx) -> dict[str, Any]:
    app.connect("builder-inited", write_task_pages)
    return {"version": "1.0", "parallel_read_safe": True, "parallel_write_safe": True}

"""The release as a user receives it: the built sdist and wheel, the wheel installed into a fresh virtualenv.

One module fixture builds both distributions (``python -m build --no-isolation``) from a copy of the
checkout's files (tracked and untracked, ignored ones left out: no stale ``build/`` of the work tree
can leak into the wheel, and the work tree gets no build output), and installs the wheel with
``pip install --no-deps`` into a fresh virtualenv outside the repository. The fresh venv takes its
dependencies (torch, Stable-Baselines3...) from the running environment through a ``.pth`` file
listing that environment's site-packages: a ``.pth`` file's lines are only added to ``sys.path``,
the ``.pth`` files in those folders are not run, so the running environment's editable install of
``seif_gym`` and ``agents`` does not come along (``test_installed_not_the_checkout`` checks it).
Everything then runs in the fresh venv's interpreter, from a folder outside the repository, without
``PYTHONPATH``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from dataclasses import dataclass
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
PROBE = Path(__file__).with_name("probe.py")
#: Top-level entries a wheel may hold besides its ``.dist-info``: the product, not the lab.
SHIPPED_PACKAGES = {"seif_gym", "agents"}
#: Files ``python -m agents.showcase`` writes to ``--out``.
SHOWCASE_FILES = ("results.csv", "summary.json", "summary.md", "map_error.png", "episode.gif")


def _tail(text: str, lines: int = 40) -> str:
    return "\n".join(text.strip().splitlines()[-lines:])


def _run(args: list[str], *, cwd: Path, env: dict[str, str] | None = None, timeout: float) -> str:
    """Run ``args``; its stdout, or a test failure showing the command and the tail of its stderr."""
    try:
        done = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired as error:
        stderr = error.stderr.decode() if isinstance(error.stderr, bytes) else (error.stderr or "")
        pytest.fail(f"{' '.join(args)} ran past {timeout} s\n--- stderr tail ---\n{_tail(stderr)}")
    if done.returncode != 0:
        pytest.fail(
            f"{' '.join(args)} exited {done.returncode} (cwd {cwd})\n"
            f"--- stderr tail ---\n{_tail(done.stderr)}\n--- stdout tail ---\n{_tail(done.stdout, 10)}"
        )
    return done.stdout


def _copy_checkout(destination: Path) -> None:
    """Copy the checkout's tracked and untracked files (ignored ones left out) to ``destination``."""
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT,
        capture_output=True,
        check=True,
    ).stdout.decode()
    for name in filter(None, listed.split("\0")):
        source = ROOT / name
        if source.is_file():  # a file deleted or moved in the work tree is still listed by the index
            target = destination / name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target)


@dataclass(frozen=True)
class Release:
    dist: Path
    sdist: Path
    wheel: Path
    venv: Path
    python: Path
    site_packages: Path
    work: Path
    env: dict[str, str]

    def run(self, *args: str, timeout: float = 600) -> str:
        """Run the fresh venv's python with ``args`` in the work folder outside the repository."""
        return _run([str(self.python), *args], cwd=self.work, env=self.env, timeout=timeout)

    def probe(self, *names: str, timeout: float = 900) -> dict:
        """The JSON of ``probe.py NAMES`` run in the fresh venv (no names: every probe)."""
        return json.loads(self.run("probe.py", *names, timeout=timeout).strip().splitlines()[-1])


@pytest.fixture(scope="module")
def release(tmp_path_factory: pytest.TempPathFactory) -> Release:
    base = tmp_path_factory.mktemp("release")
    source, dist, venv, work = base / "source", base / "dist", base / "venv", base / "work"
    work.mkdir()
    _copy_checkout(source)
    # no network: the running environment's setuptools builds (the build-system requires only setuptools>=77,
    # which builds wheels itself; a too-old setuptools fails the dependency check)
    _run(
        [
            sys.executable,
            "-m",
            "build",
            "--sdist",
            "--wheel",
            "--no-isolation",
            "--outdir",
            str(dist),
            str(source),
        ],
        cwd=base,
        timeout=900,
    )
    (sdist,) = dist.glob("*.tar.gz")
    (wheel,) = dist.glob("*.whl")

    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], cwd=base, timeout=300)
    python = venv / "bin" / "python"
    # the running pip installs into the fresh venv's interpreter, before that venv sees any other
    # site-packages (so pip finds no seif-gym installed there to replace)
    _run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-index", "-q", str(wheel)],
        cwd=base,
        timeout=600,
    )
    site_packages = Path(
        _run(
            [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=work, timeout=120
        ).strip()
    )
    ours = sysconfig.get_paths()
    borrowed = list(dict.fromkeys([ours["purelib"], ours["platlib"]]))
    (site_packages / "_release_test_dependencies.pth").write_text("".join(f"{path}\n" for path in borrowed))

    shutil.copy(PROBE, work / PROBE.name)
    env = {key: value for key, value in os.environ.items() if key not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    env.update(
        OMP_NUM_THREADS="1",
        OPENBLAS_NUM_THREADS="1",
        MKL_NUM_THREADS="1",
        MPLBACKEND="Agg",
        VIRTUAL_ENV=str(venv),
        PATH=f"{venv / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}",
    )
    return Release(dist, sdist, wheel, venv, python, site_packages, work, env)


@pytest.fixture(scope="module")
def probed(release: Release) -> dict:
    """Every probe of ``probe.py``, run once in the fresh venv (one torch import for all of them)."""
    return release.probe()


def test_twine_check(release: Release) -> None:
    _run(
        [sys.executable, "-m", "twine", "check", "--strict", str(release.sdist), str(release.wheel)],
        cwd=release.dist,
        timeout=300,
    )


def test_wheel_holds_only_the_product(release: Release) -> None:
    with zipfile.ZipFile(release.wheel) as wheel:
        names = wheel.namelist()
    top = {name.split("/", 1)[0] for name in names}
    dist_info = {entry for entry in top if entry.endswith(".dist-info")}
    assert len(dist_info) == 1, f"expected one .dist-info in {release.wheel.name}, found {sorted(dist_info)}"
    assert top - dist_info == SHIPPED_PACKAGES, (
        f"{release.wheel.name} holds {sorted(top - dist_info)}; only {sorted(SHIPPED_PACKAGES)} and the dist-info "
        "are shipped"
    )


def test_installed_not_the_checkout(release: Release, probed: dict) -> None:
    found = probed["where"]
    venv = release.venv.resolve()
    for package in ("seif_gym", "agents"):
        location = Path(found[package]).resolve()
        assert location.is_relative_to(venv), f"{package} imported from {location}, not from the fresh venv {venv}"
    assert found["version"] in release.wheel.name, f"seif_gym.__version__ {found['version']} is not the wheel's"
    assert found["research_error"] is not None, "`import research` works in the fresh venv: the lab is not shipped"
    assert not found["editable_modules"], f"an editable finder came along: {found['editable_modules']}"
    assert not [finder for finder in found["meta_path"] if "editable" in finder.lower()], found["meta_path"]
    paths = [Path(entry).resolve() for entry in found["sys_path"] if entry]
    assert ROOT not in paths, f"the checkout {ROOT} is on the fresh venv's sys.path: {found['sys_path']}"
    others = [
        str(path)
        for path in paths
        if path != release.site_packages.resolve() and any((path / package).exists() for package in SHIPPED_PACKAGES)
    ]
    assert not others, f"seif_gym or agents also importable from {others} in the fresh venv"


def test_every_registered_task_steps(probed: dict) -> None:
    failures = {env_id: error for env_id, error in probed["tasks"].items() if error is not None}
    assert not failures, "tasks that fail from the installed wheel:\n" + "\n\n".join(
        f"{env_id}:\n{error}" for env_id, error in failures.items()
    )


def test_pretrained_policies_play_an_episode(probed: dict) -> None:
    episodes = probed["pretrained"]
    assert len(episodes) == 7, f"expected the leaderboard's 7 -v2 tasks, got {sorted(episodes)}"
    assert all(env_id.endswith("-v2") for env_id in episodes), sorted(episodes)
    failures = {env_id: run["error"] for env_id, run in episodes.items() if run["error"] is not None}
    assert not failures, "shipped policies that fail from the installed wheel:\n" + "\n\n".join(
        f"{env_id}:\n{error}" for env_id, error in failures.items()
    )
    outside = {env_id: run["outside"] for env_id, run in episodes.items() if run["outside"]}
    assert not outside, f"actions outside the action space (task: how many): {outside}"
    assert all(run["steps"] > 0 for run in episodes.values()), episodes


def test_showcase_runs(release: Release) -> None:
    out = release.work / "showcase"
    release.run("-m", "agents.showcase", "--episodes", "2", "--out", str(out), "--quiet", timeout=900)
    missing = [name for name in SHOWCASE_FILES if not (out / name).is_file() or (out / name).stat().st_size == 0]
    assert not missing, f"agents.showcase did not write {missing} to {out}"

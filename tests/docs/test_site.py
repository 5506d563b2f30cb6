"""The documentation site builds without a warning and works in a browser.

The site is built with ``sphinx-build -W`` (a warning fails the build) into
``docs/_build/site_test``, served over http://127.0.0.1 as a reader's browser
would get it, and headless Chromium opens the landing page, a task page, the
API reference and the leaderboard. On each page: no console error (an
uncaught exception, a ``console.error``, a resource that failed to load), every
image loaded, and every link to the site itself (relative, or to the same
origin) resolves to a file of the build and, with a fragment, to an element
with that id. Screenshots of the landing page and the task page are saved in
``docs/_build/site_test/_screenshots/`` for a person to look at.

Chromium is driven through its DevTools protocol over a pipe
(``--remote-debugging-pipe``: JSON messages separated by NUL bytes on file
descriptors 3 and 4), so the test needs no Python package beyond the docs
extra; it skips only where no ``chromium`` is installed.
"""

from __future__ import annotations

import base64
import fcntl
import functools
import html
import http.server
import json
import os
import queue
import re
import shutil
import subprocess
import sys
import threading
import time
import urllib.parse
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
BUILD = ROOT / "docs" / "_build" / "site_test"
SCREENSHOTS = BUILD / "_screenshots"
#: Pages opened in the browser: the landing page, a task, the API reference, the leaderboard.
PAGES = ("index.html", "tasks/{task}.html", "api/index.html", "api/slam.html", "benchmark/leaderboard.html")
SCREENSHOT_PAGES = {"index.html": "index.png", "tasks/{task}.html": "task.png"}


# -- the build ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def site() -> Path:
    """The site, built afresh (``-E``: every page read again, so that every warning is seen) with ``-W``."""
    if BUILD.exists():
        shutil.rmtree(BUILD)
    command = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-E", "-q", "-b", "html", "docs", str(BUILD)]
    started = time.perf_counter()
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=1800)
    print(f"sphinx-build: {time.perf_counter() - started:.0f} s")
    assert result.returncode == 0, f"sphinx-build -W failed:\n{result.stdout[-4000:]}\n{result.stderr[-8000:]}"
    assert "WARNING" not in result.stderr, result.stderr[-8000:]
    assert (BUILD / "index.html").is_file()
    return BUILD


@pytest.fixture(scope="module")
def server(site: Path) -> Iterator[str]:
    """The build served at http://127.0.0.1:PORT/, shut down after the module."""

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, format: str, *args: Any) -> None:  # noqa: A002  (the base class's name)
            pass

    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Quiet, directory=str(site)))
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{httpd.server_address[1]}/"
    finally:
        httpd.shutdown()
        httpd.server_close()
        thread.join(timeout=10)


# -- Chromium over the DevTools protocol ---------------------------------------------------------------


def high_fd(fd: int) -> int:
    """``fd`` moved to a number of 10 or more (so that the child's 3 and 4 can be set without a clash)."""
    moved = fcntl.fcntl(fd, fcntl.F_DUPFD, 10)
    os.close(fd)
    return moved


class Chromium:
    """Headless Chromium and one tab, driven by DevTools messages over ``--remote-debugging-pipe``."""

    def __init__(self, executable: str, profile: Path) -> None:
        to_browser_read, to_browser_write = (high_fd(fd) for fd in os.pipe())
        from_browser_read, from_browser_write = (high_fd(fd) for fd in os.pipe())
        flags = [
            "--headless",
            "--disable-gpu",
            "--remote-debugging-pipe",
            f"--user-data-dir={profile}",
            "--no-first-run",
            "--no-default-browser-check",
            "--disable-extensions",
            "--disable-background-networking",
            "--disable-component-update",
            "--hide-scrollbars",
            "--window-size=1280,900",
            "about:blank",
        ]
        if hasattr(os, "geteuid") and os.geteuid() == 0:
            flags.append("--no-sandbox")  # Chromium refuses to start as root with its sandbox
        # the browser reads commands on fd 3 and writes replies on fd 4: a small Python launcher puts the pipes
        # there and becomes Chromium (no preexec_fn, which is unsafe beside the server's thread)
        launcher = "import os, sys; os.dup2(int(sys.argv[1]), 3); os.dup2(int(sys.argv[2]), 4); os.execv(sys.argv[3], sys.argv[3:])"
        self.process = subprocess.Popen(
            [sys.executable, "-c", launcher, str(to_browser_read), str(from_browser_write), executable, *flags],
            pass_fds=(to_browser_read, from_browser_write),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        os.close(to_browser_read)
        os.close(from_browser_write)
        self.writer = os.fdopen(to_browser_write, "wb", buffering=0)
        self.reader = os.fdopen(from_browser_read, "rb", buffering=0)
        self.messages: queue.Queue[dict[str, Any] | None] = queue.Queue()
        self.events: list[dict[str, Any]] = []
        self.next_id = 0
        threading.Thread(target=self._read, daemon=True).start()
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self.session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        for domain in ("Runtime", "Log", "Page", "Network"):
            self.call(f"{domain}.enable", session=True)
        self.call("Page.setLifecycleEventsEnabled", session=True, enabled=True)

    def _read(self) -> None:
        buffer = b""
        while True:
            chunk = self.reader.read(65536)
            if not chunk:
                self.messages.put(None)
                return
            buffer += chunk
            *complete, buffer = buffer.split(b"\0")
            for message in complete:
                self.messages.put(json.loads(message))

    def _next(self, deadline: float) -> dict[str, Any]:
        try:
            message = self.messages.get(timeout=max(deadline - time.monotonic(), 0.01))
        except queue.Empty:
            raise AssertionError("Chromium did not answer in time") from None
        if message is None:
            raise AssertionError("Chromium closed its DevTools pipe")
        return message

    def call(self, method: str, session: bool = False, timeout: float = 60.0, **params: Any) -> dict[str, Any]:
        """Send one command (to the tab with ``session``) and return its result; events seen meanwhile are kept."""
        self.next_id += 1
        message: dict[str, Any] = {"id": self.next_id, "method": method, "params": params}
        if session:
            message["sessionId"] = self.session
        self.writer.write(json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            reply = self._next(deadline)
            if reply.get("id") == self.next_id:
                assert "error" not in reply, f"{method}: {reply['error']}"
                return reply.get("result", {})
            if "method" in reply:
                self.events.append(reply)

    def wait_for(self, predicate: Any, timeout: float) -> bool:
        """Collect events until one satisfies ``predicate`` (True) or ``timeout`` seconds pass (False)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                event = self._next(deadline)
            except AssertionError:
                return False
            self.events.append(event)
            if predicate(event):
                return True
        return False

    def evaluate(self, expression: str) -> Any:
        result = self.call(
            "Runtime.evaluate", session=True, expression=expression, awaitPromise=True, returnByValue=True
        )
        assert "exceptionDetails" not in result, result["exceptionDetails"]
        return result["result"].get("value")

    def open(self, url: str) -> list[str]:
        """Load ``url`` until the network is idle; the console errors it caused."""
        self.events.clear()
        self.call("Page.navigate", session=True, url=url)
        loaded = self.wait_for(lambda e: e.get("method") == "Page.loadEventFired", timeout=60)
        assert loaded, f"{url} did not finish loading"
        self.wait_for(
            lambda e: e.get("method") == "Page.lifecycleEvent" and e["params"].get("name") == "networkIdle", timeout=10
        )
        self.wait_for(lambda e: False, timeout=0.5)  # errors logged just after the load
        return console_errors(self.events)

    def screenshot(self, path: Path, full_page: bool) -> None:
        params: dict[str, Any] = {"format": "png"}
        if full_page:
            size = self.call("Page.getLayoutMetrics", session=True)["cssContentSize"]
            height = min(size["height"], 6000)
            params.update(
                captureBeyondViewport=True, clip={"x": 0, "y": 0, "width": 1280, "height": height, "scale": 1}
            )
        data = self.call("Page.captureScreenshot", session=True, **params)["data"]
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(base64.b64decode(data))

    def close(self) -> None:
        try:
            self.call("Browser.close", timeout=10)
        except AssertionError:
            pass
        try:
            self.process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(timeout=20)
        self.writer.close()
        self.reader.close()


def console_errors(events: list[dict[str, Any]]) -> list[str]:
    """What a reader would see as errors in the browser's console, from the DevTools events."""
    errors = []
    for event in events:
        method, params = event.get("method"), event.get("params", {})
        if method == "Runtime.exceptionThrown":
            details = params["exceptionDetails"]
            errors.append(f"exception: {details.get('exception', {}).get('description') or details.get('text')}")
        elif method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
            errors.append(
                "console.error: " + " ".join(str(a.get("value", a.get("description"))) for a in params["args"])
            )
        elif method == "Log.entryAdded" and params["entry"].get("level") == "error":
            entry = params["entry"]
            errors.append(f"{entry.get('source')}: {entry.get('text')} {entry.get('url', '')}".strip())
        elif method == "Network.loadingFailed" and not params.get("canceled"):
            errors.append(f"failed to load: {params.get('errorText')} ({params.get('type')})")
    return errors


@pytest.fixture(scope="module")
def browser(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Chromium]:
    executable = shutil.which("chromium")
    if executable is None:
        pytest.skip("no chromium on PATH: the site's browser checks need it (apt-get install chromium)")
    chromium = Chromium(executable, tmp_path_factory.mktemp("chromium-profile"))
    try:
        yield chromium
    finally:
        chromium.close()


# -- links ---------------------------------------------------------------------------------------------


@functools.cache
def element_ids(path: Path) -> frozenset[str]:
    text = path.read_text(encoding="utf-8", errors="replace")
    return frozenset(html.unescape(m.group(2)) for m in re.finditer(r"""\s(id|name)=["']([^"']+)["']""", text))


def broken_links(hrefs: list[str], base: str, site: Path) -> list[str]:
    """The links to the site itself that lead to no file of the build, or to no element of its fragment."""
    broken = []
    for href in sorted(set(hrefs)):
        if not href.startswith(base):
            continue  # another origin (or mailto:, javascript:): not the site's to check
        parsed = urllib.parse.urlsplit(href)
        relative = urllib.parse.unquote(parsed.path).lstrip("/")
        target = site / relative
        if relative == "" or relative.endswith("/"):
            target = target / "index.html"
        if not target.resolve().is_relative_to(site.resolve()) or not target.is_file():
            broken.append(f"{href}: no such file in the build")
            continue
        fragment = urllib.parse.unquote(parsed.fragment)
        if fragment and target.suffix == ".html" and fragment not in element_ids(target):
            broken.append(f"{href}: no element with id {fragment!r} in {relative or 'index.html'}")
    return broken


IMAGES = """
Promise.all(Array.from(document.images).map(img => {
    img.loading = "eager";
    return (img.complete ? Promise.resolve() : new Promise(done => { img.onload = done; img.onerror = done; }))
        .then(() => img.decode().catch(() => null));
})).then(() => Array.from(document.images).map(img => ({src: img.currentSrc || img.src, width: img.naturalWidth})))
"""
LINKS = "Array.from(document.querySelectorAll('a[href], link[href]')).map(a => a.href)"


# -- the tests -----------------------------------------------------------------------------------------


def task_page() -> str:
    import seif_gym

    return seif_gym.LATEST_ID


@pytest.mark.parametrize("page", PAGES)
def test_page_works_in_a_browser(page: str, site: Path, server: str, browser: Chromium) -> None:
    page = page.format(task=task_page())
    assert (site / page).is_file(), f"{page} is not in the build"
    errors = browser.open(server + page)
    assert errors == [], f"{page}: console errors: {errors}"

    images = browser.evaluate(IMAGES)
    not_loaded = [image["src"] for image in images if not image["width"]]
    assert not not_loaded, f"{page}: images that did not load: {not_loaded}"

    broken = broken_links(browser.evaluate(LINKS), server, site)
    assert not broken, f"{page}: " + "; ".join(broken)

    if page.replace(task_page(), "{task}") in SCREENSHOT_PAGES:
        name = SCREENSHOT_PAGES[page.replace(task_page(), "{task}")]
        browser.screenshot(SCREENSHOTS / name, full_page=name != "index.png")
        assert (SCREENSHOTS / name).stat().st_size > 10_000


def test_task_page_shows_its_episode(site: Path, server: str, browser: Chromium) -> None:
    """The task page's GIF is an animation of the episode, not a still."""
    browser.open(server + f"tasks/{task_page()}.html")
    gifs = [image["src"] for image in browser.evaluate(IMAGES) if image["src"].endswith(".gif")]
    assert len(gifs) == 1, gifs
    data = (site / urllib.parse.unquote(urllib.parse.urlsplit(gifs[0]).path).lstrip("/")).read_bytes()
    assert data[:6] in (b"GIF87a", b"GIF89a")
    assert data.count(b"\x21\xf9\x04") > 10, "fewer than 10 frames"  # one graphic control extension per frame


def test_every_page_of_the_build_is_reachable_from_the_index(site: Path, server: str, browser: Chromium) -> None:
    """The navigation reaches every page Sphinx wrote (apart from its own search and index pages)."""
    browser.open(server + "index.html")
    linked = {
        urllib.parse.unquote(urllib.parse.urlsplit(href).path).lstrip("/")
        for href in browser.evaluate(LINKS)
        if href.startswith(server)
    }
    pages = {
        path.relative_to(site).as_posix()
        for path in site.rglob("*.html")
        if not path.relative_to(site).parts[0].startswith("_")
        and path.name not in ("search.html", "genindex.html")
        and path.name != "py-modindex.html"
    }
    assert pages - linked - {"index.html"} == set(), "pages the landing page's navigation does not list"

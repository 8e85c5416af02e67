"""The documentation site, built with ``mkdocs build --strict`` and opened page by page in headless Chromium.

Every built page is served over HTTP on 127.0.0.1 and checked in the browser: no request of the page fails (and none
leaves the site: it must work offline), no console error, every ``<video>`` loads its metadata, the maths is rendered
(KaTeX, vendored under ``docs/javascripts/``), API signatures are formatted, every link and image inside the site
resolves to a built file (and anchor). Search finds the algorithm over HTTP and on a page opened from disk.
Screenshots of a few pages land in ``site-screenshots/`` for a reader of the build's artefacts.

The browser is Debian's Chromium (``apt-get install chromium``), driven by Playwright: without it, or without
Playwright or MkDocs, the test fails when ``CI`` is set and is skipped otherwise.
"""

from __future__ import annotations

import functools
import http.server
import importlib.util
import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urldefrag, urlsplit

import pytest

pytestmark = pytest.mark.slow  # a site build and a browser: about a minute

REPO = Path(__file__).resolve().parents[1]
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
SCREENSHOTS = REPO / "site-screenshots"
SCREENSHOT_PAGES = ["index.html", "algorithm.html", "results.html", "api.html"]
SCREENSHOT_HEIGHT = 2400  # pixels: the results and API pages are tens of thousands of pixels tall
VIEWPORT = {"width": 1280, "height": 900}
SEARCH_TERM = "TRPOPlus"
VIDEO_TIMEOUT_MS = 15_000
SIGNATURE_LINE = 100  # characters: mkdocstrings formats signatures (with ruff) to 60 a line; unformatted, one long line
REPORTED_PER_PAGE = 12

# Resolves, for every <video> of the page, once its metadata has loaded, it failed, or the time is up.
VIDEOS_JS = """
(timeout) => Promise.all(Array.from(document.querySelectorAll("video"), (video) => new Promise((resolve) => {
  const done = () => resolve({
    src: video.currentSrc || video.src || (video.querySelector("source") || {}).src || "",
    readyState: video.readyState,
    duration: video.duration,
    error: video.error ? video.error.code : null,
  });
  if (video.readyState >= 1 || video.error) { done(); return; }
  video.addEventListener("loadedmetadata", done, { once: true });
  video.addEventListener("error", done, { once: true });
  for (const source of video.querySelectorAll("source")) source.addEventListener("error", done, { once: true });
  if (video.preload === "none") { video.preload = "metadata"; video.load(); }
  setTimeout(done, timeout);
})))
"""

PAGE_FACTS_JS = """
() => ({
  text: document.body.innerText,
  maths: document.querySelectorAll(".arithmatex").length,
  unrendered: Array.from(document.querySelectorAll(".arithmatex"))
    .filter((element) => !element.querySelector(".katex") || element.querySelector(".katex-error"))
    .map((element) => element.textContent.slice(0, 120)),
  links: Array.from(document.querySelectorAll("a[href]"), (a) => a.href),
  images: Array.from(document.querySelectorAll("img[src]"), (img) => img.src),
  ids: Array.from(document.querySelectorAll("[id]"), (element) => element.id),
  signatures: Array.from(document.querySelectorAll(".doc-signature"), (element) => element.innerText),
})
"""


def _unavailable(reason: str) -> None:
    """Fail in CI, where the site must be tested; skip elsewhere."""
    if os.environ.get("CI", "").lower() not in ("", "0", "false", "no"):
        pytest.fail(f"{reason} (CI is set: the documentation site must be tested)", pytrace=False)
    pytest.skip(reason)


def _requirements() -> None:
    if not CHROMIUM.exists():
        _unavailable(f"{CHROMIUM} is missing: apt-get install chromium")
    for module in ("playwright", "mkdocs"):
        if importlib.util.find_spec(module) is None:
            _unavailable(f"{module} is not installed: pip install -e '.[test,docs]'")


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args: Any) -> None:  # the base class names it format
        pass


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The site, built from this checkout as ``make docs`` builds it."""
    _requirements()
    site_dir = tmp_path_factory.mktemp("site") / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    command = [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site_dir)]
    result = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    if result.returncode != 0:
        pytest.fail(f"mkdocs build --strict failed:\n{result.stdout}\n{result.stderr}", pytrace=False)
    return site_dir


@pytest.fixture(scope="module")
def base_url(site: Path) -> Iterator[str]:
    handler = functools.partial(_QuietHandler, directory=str(site))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    server.daemon_threads = True
    thread = threading.Thread(target=server.serve_forever, name="site-server", daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/"
    finally:
        server.shutdown()
        server.server_close()
        thread.join(timeout=10)


@pytest.fixture(scope="module")
def browser_context(site: Path) -> Iterator[Any]:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            context = browser.new_context(viewport=VIEWPORT)
            context.set_default_timeout(30_000)
            yield context
            context.close()
        finally:
            browser.close()


def _pages(site: Path) -> list[str]:
    """Every built page, relative to the site (the 404 page and the search assets left out)."""
    pages = [
        path.relative_to(site).as_posix()
        for path in site.rglob("*.html")
        if path.name != "404.html" and "search" not in path.relative_to(site).parts
    ]
    return sorted(pages)


def _site_file(site: Path, base_url: str, url: str) -> Path | None:
    """The built file a URL of the site names, or None for a URL outside the site."""
    if not url.startswith(base_url):
        return None
    return site / unquote(urlsplit(url).path).lstrip("/")


class _PageProblems:
    """What went wrong while one page loaded: failed requests, error responses, console errors, requests elsewhere."""

    def __init__(self, page: Any, base_url: str) -> None:
        self.problems: list[str] = []
        self.base_url = base_url
        page.on("requestfailed", lambda request: self.problems.append(f"request failed: {request.url} ({request.failure})"))
        page.on("response", self._response)
        page.on("request", self._request)
        page.on("console", lambda message: message.type == "error" and self.problems.append(f"console: {message.text}"))
        page.on("pageerror", lambda error: self.problems.append(f"page error: {error}"))

    def _response(self, response: Any) -> None:
        if response.url.startswith(self.base_url) and response.status >= 400:
            self.problems.append(f"HTTP {response.status}: {response.url}")

    def _request(self, request: Any) -> None:
        if urlsplit(request.url).scheme in ("http", "https", "ws", "wss") and not request.url.startswith(self.base_url):
            self.problems.append(f"request leaves the site (offline it fails): {request.url}")


def test_site_in_a_browser(site: Path, base_url: str, browser_context: Any) -> None:
    """Every page loads and renders, its links resolve, and search works over HTTP and from disk.

    One test, one build and one browser (split into tests, the build and the browser would be made on every xdist worker
    that runs one of them): the problems of every check are gathered and reported together.
    """
    pages = _pages(site)
    assert "index.html" in pages and "results.html" in pages and "api.html" in pages, pages
    SCREENSHOTS.mkdir(exist_ok=True)
    problems: dict[str, list[str]] = {}
    links: dict[str, set[str]] = {}  # URL linked or shown -> the pages that link or show it
    ids: dict[Path, set[str]] = {}
    counts = {"video": 0, "maths": 0, "signature": 0}
    for name in pages:
        page = browser_context.new_page()
        recorder = _PageProblems(page, base_url)
        facts = _check_page(page, base_url + name, recorder.problems)
        for url in facts["links"] + facts["images"]:
            links.setdefault(url, set()).add(name)
        ids[site / name] = set(facts["ids"])
        counts["video"] += facts["videos"]
        counts["maths"] += facts["maths"]
        counts["signature"] += len(facts["signatures"])
        if name in SCREENSHOT_PAGES:
            _screenshot(page, name)
        problems[name] = list(recorder.problems)  # before closing: closing aborts what is still loading
        page.close()
    for url, sources in sorted(links.items()):
        for problem in _link_problems(site, base_url, url, ids):
            for source in sorted(sources):
                problems[source].append(problem)
    problems["search over HTTP"] = _search_problems(browser_context, base_url, base_url + "index.html", "search.png")
    problems["search from disk"] = _search_problems(browser_context, base_url, (site / "index.html").as_uri(), None)

    lines = []
    for name, found in problems.items():
        lines += [f"{name}: {problem}" for problem in found[:REPORTED_PER_PAGE]]
        if len(found) > REPORTED_PER_PAGE:
            lines.append(f"{name}: ... and {len(found) - REPORTED_PER_PAGE} more")
    report = "\n".join(lines)
    assert not report, f"the site has problems:\n{report}"
    unchecked = [what for what, count in counts.items() if count == 0]
    assert not unchecked, f"no {' and no '.join(unchecked)} on any page: those checks checked nothing"


def _check_page(page: Any, url: str, found: list[str]) -> dict[str, Any]:
    """Loads the page, appends what is wrong with it to found, and returns its facts (PAGE_FACTS_JS)."""
    page.goto(url, wait_until="load")
    videos = page.evaluate(VIDEOS_JS, VIDEO_TIMEOUT_MS)
    for video in videos:
        if video["error"] is not None or video["readyState"] < 1 or not video["duration"] > 0:
            found.append(f"video without metadata: {video}")
    page.wait_for_load_state("networkidle")
    facts: dict[str, Any] = page.evaluate(PAGE_FACTS_JS)
    facts["videos"] = len(videos)
    found += [f"maths not rendered: {text!r}" for text in facts["unrendered"]]
    for raw in ("\\(", "$$"):
        at = facts["text"].find(raw)
        if at >= 0:
            found.append(f"raw {raw!r} in the rendered text: {facts['text'][max(at - 60, 0) : at + 60]!r}")
    for signature in facts["signatures"]:
        if max(len(line) for line in signature.splitlines()) > SIGNATURE_LINE:
            found.append(f"signature not formatted (is ruff installed?): {signature[:100]!r}...")
    return facts


def _link_problems(site: Path, base_url: str, url: str, ids: dict[Path, set[str]]) -> list[str]:
    """A link or image inside the site must name a built file (not a folder) and, with a fragment, an id on that page."""
    address, fragment = urldefrag(url)
    target = _site_file(site, base_url, address)
    if target is None:
        return []
    if not target.is_file():
        return [f"link to {url}: " + ("a folder (a listing when opened from disk)" if target.is_dir() else "missing")]
    if fragment and target in ids and unquote(fragment) not in ids[target]:
        return [f"link to {url}: no element with id {fragment!r}"]
    return []


def _screenshot(page: Any, name: str) -> None:
    """The top of the page (at most SCREENSHOT_HEIGHT pixels) and, where it has videos, the first of them in view."""
    stem = name.removesuffix(".html")
    height = min(page.evaluate("document.documentElement.scrollHeight"), SCREENSHOT_HEIGHT)
    clip = {"x": 0, "y": 0, "width": VIEWPORT["width"], "height": height}
    page.screenshot(path=str(SCREENSHOTS / f"{stem}.png"), full_page=True, clip=clip)
    videos = page.locator("video")
    if videos.count():
        videos.first.scroll_into_view_if_needed()
        # a frame to show (metadata alone leaves the player blank), and the header's title done fading on scroll
        videos.first.evaluate(
            "(video, timeout) => video.readyState >= 2 || new Promise((resolve) => {"
            " video.addEventListener('loadeddata', resolve, { once: true }); setTimeout(resolve, timeout); })",
            VIDEO_TIMEOUT_MS,
        )
        page.wait_for_timeout(500)
        page.screenshot(path=str(SCREENSHOTS / f"{stem}-videos.png"))


def _search_problems(context: Any, base_url: str, url: str, screenshot: str | None) -> list[str]:
    """Types the search term into Material's search box on the page at url: what went wrong, if anything.

    Opened from disk (file://), search works through the offline plugin: the index is a script, the worker an iframe.
    """
    from playwright.sync_api import Error as PlaywrightError

    page = context.new_page()
    recorder = _PageProblems(page, base_url)
    try:
        page.goto(url, wait_until="load")
        box = page.locator("input.md-search__input")
        box.click()
        # Material says "Initializing search" until its worker has the index: a query typed before is lost
        page.wait_for_function("() => !document.querySelector('.md-search-result__meta').textContent.includes('Initializing')")
        box.press_sequentially(SEARCH_TERM)  # key by key: Material searches on keyup, which fill() does not send
        results = page.locator(".md-search-result__item")
        results.first.wait_for(state="visible")
        if screenshot:
            page.screenshot(path=str(SCREENSHOTS / screenshot))
    except PlaywrightError as error:
        recorder.problems.append(f"no results for {SEARCH_TERM!r}: {error.message.splitlines()[0]}")
    finally:
        found = list(recorder.problems)
        page.close()
    return found

"""The report page in a real browser: Debian's chromium driven by playwright (PyPI).

:func:`check_page` opens ``index.html`` from disk in headless chromium with a fresh profile
and no network features, and reports what a reader would hit: console errors and page
errors, requests that failed, images that did not load (``naturalWidth == 0``) and tables
without rows. playwright's own browser downloads are never used: the browser is the
system's (``/usr/bin/chromium`` on Debian, ``apt-get install chromium``), or ``--browser``.
"""
from __future__ import annotations

import importlib.util
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

#: where a system chromium is looked for, in order
BROWSERS = ("/usr/bin/chromium", "/usr/bin/chromium-browser", "chromium", "chromium-browser", "google-chrome")
#: flags for a headless run as root in a container, with nothing reaching the network
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-dev-shm-usage")


class BrowserUnavailable(RuntimeError):
    """No chromium, or no playwright, on this machine."""


@dataclass
class PageCheck:
    """What the browser saw; ``ok`` when nothing went wrong."""
    browser: str
    console_errors: list = field(default_factory=list)
    failed_requests: list = field(default_factory=list)
    images: int = 0
    broken_images: list = field(default_factory=list)
    tables: int = 0
    empty_tables: list = field(default_factory=list)
    width_px: int = 0
    overflow_px: int = 0        # how far the page scrolls sideways outside its scroll boxes

    @property
    def ok(self) -> bool:
        return not (self.console_errors or self.failed_requests or self.broken_images or self.empty_tables
                    or self.overflow_px > 0)

    def summary(self) -> str:
        head = (f"browser check ({self.browser}): {self.images} images, {self.tables} tables, "
                f"{len(self.console_errors)} console errors")
        problems = ([f"console: {m}" for m in self.console_errors] + [f"request failed: {r}" for r in
                    self.failed_requests] + [f"image not loaded: {s}" for s in self.broken_images]
                    + [f"table without rows: {t}" for t in self.empty_tables]
                    + ([f"the page is {self.overflow_px} px wider than a {self.width_px} px window"]
                       if self.overflow_px > 0 else []))
        return head + (": ok" if self.ok else "\n  " + "\n  ".join(problems))


def find_browser(explicit: str | None = None) -> str | None:
    """Path of a chromium to drive (None when there is none, or playwright is not installed)."""
    if importlib.util.find_spec("playwright") is None:
        return None
    for name in ((explicit,) if explicit else BROWSERS):
        path = shutil.which(name) if name else None
        if path:
            return path
    return None


_PROBE = """() => ({
  images: [...document.images].map(i => ({src: i.getAttribute('src'), ok: i.complete && i.naturalWidth > 0})),
  tables: [...document.querySelectorAll('table')].map((t, k) => ({
      name: (t.caption ? t.caption.textContent : '') || (t.closest('section') || {}).id || ('table ' + k),
      rows: t.tBodies.length ? t.tBodies[0].rows.length : 0})),
  overflow: document.documentElement.scrollWidth - window.innerWidth,
})"""


def check_page(index, browser: str | None = None, timeout_s: float = 60.0, width_px: int = 1280) -> PageCheck:
    """Open ``index`` (an HTML file) in headless chromium, in a window ``width_px`` wide, and check it:
    console errors, failed requests, broken images, empty tables, and sideways overflow of the page
    itself (wide tables scroll inside their own box).

    Raises
    ------
    BrowserUnavailable
        When playwright or a chromium is missing.
    FileNotFoundError
        When ``index`` does not exist.
    """
    index = Path(index).resolve()
    if not index.is_file():
        raise FileNotFoundError(f"{index}: no such page")
    exe = find_browser(browser)
    if exe is None:
        raise BrowserUnavailable("no browser to check the page: apt-get install chromium and pip install "
                                 "playwright (never `playwright install`)")
    from playwright.sync_api import sync_playwright   # here: playwright is optional (the browser extra)
    result = PageCheck(browser=exe, width_px=int(width_px))
    with tempfile.TemporaryDirectory(prefix="deapull-chromium-") as profile, sync_playwright() as pw:
        context = pw.chromium.launch_persistent_context(profile, executable_path=exe, headless=True,
                                                        args=list(FLAGS), timeout=timeout_s * 1e3)
        try:
            page = context.new_page()
            page.set_viewport_size({"width": int(width_px), "height": 900})
            page.on("console", lambda m: result.console_errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: result.console_errors.append(str(e)))
            page.on("requestfailed", lambda r: result.failed_requests.append(f"{r.url} ({r.failure})"))
            page.goto(index.as_uri(), wait_until="load", timeout=timeout_s * 1e3)
            probe = page.evaluate(_PROBE)
        finally:
            context.close()
    result.images = len(probe["images"])
    result.broken_images = [i["src"] for i in probe["images"] if not i["ok"]]
    result.tables = len(probe["tables"])
    result.empty_tables = [t["name"] for t in probe["tables"] if t["rows"] == 0]
    result.overflow_px = max(int(probe["overflow"]), 0)
    return result

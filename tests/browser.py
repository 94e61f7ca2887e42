"""The browser tests' one setup: Debian's chromium driven by Playwright, a dashboard page logged in
with an API key, and the page's JavaScript errors collected (``page.js_errors``); the three.js
harness (``tests/threejs.py``) opens its page in the same chromium."""

from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path

CHROMIUM = Path(os.environ.get("FARFIELD_CHROMIUM", "/usr/bin/chromium"))
CHROMIUM_ARGS = [
    "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--disable-background-networking",
    "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-quic",
    # WebGL for the three.js harness (tests/threejs.py): chromium's software renderer (ANGLE on
    # SwiftShader), which newer builds no longer fall back to without this flag.
    "--enable-unsafe-swiftshader",
]  # fmt: skip
SKIP_REASON = f"needs Debian's chromium at {CHROMIUM} (scripts/install-browser installs it)"


def tid(name: str) -> str:
    """The CSS selector of a ``data-testid``."""
    return f'[data-testid="{name}"]'


@contextmanager
def launched_browser():
    """Headless chromium (the caller skips first when :data:`CHROMIUM` is missing)."""
    from playwright import sync_api

    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()


def new_page(browser, url: str):
    """A page of the dashboard at ``url`` in a fresh browser context, collecting its JavaScript errors."""
    context = browser.new_context(viewport={"width": 1400, "height": 1000})
    page = context.new_page()
    page.set_default_timeout(30_000)
    page.js_errors = []
    page.on("pageerror", lambda error: page.js_errors.append(str(error)))
    page.goto(url + "/")
    return page


@contextmanager
def dashboard_page(browser, url: str, key: str):
    """A dashboard page already holding ``key`` (as if pasted once), closed afterwards."""
    page = new_page(browser, url)
    try:
        page.evaluate(f"localStorage.setItem('farfield.apiKey', '{key}')")
        page.goto(url + "/#/")
        page.reload()
        yield page
    finally:
        page.context.close()

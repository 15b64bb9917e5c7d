"""Browser tests: Debian's chromium driven by Playwright, against the real system.

Playwright's own browser download is never used: ``.ci/run`` installs Debian's chromium and
the tests launch ``/usr/bin/chromium`` (or ``$ANKLE_CHROMIUM``). Screenshots of every page go
to ``test-output/screenshots/`` for a person to look at.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest
from playwright.sync_api import (
    Browser,
    BrowserContext,
    ConsoleMessage,
    Page,
    expect,
    sync_playwright,
)

from tests.server.redis_server import redis_server, relay_url
from tests.system.harness import device_args, stack, system

__all__ = [
    "browser",
    "context",
    "device_args",
    "page",
    "redis_server",
    "relay_url",
    "shots",
    "stack",
    "system",
]

ROOT = Path(__file__).resolve().parents[2]
WAIT_MS = 15_000
"""How long a page action or an ``expect`` waits for its condition. Playwright's ``expect``
gives up after 5 s by default: too short for a page on a loaded 2-core machine, where a
condition that holds a second later is no failure."""
expect.set_options(timeout=WAIT_MS)
SCREENSHOTS = ROOT / "test-output" / "screenshots"
CHROMIUM_FLAGS = [
    "--no-sandbox",  # CI runs as root
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--use-gl=angle",
    "--use-angle=swiftshader",  # software WebGL for the viser 3D view
    "--enable-unsafe-swiftshader",
]


def chromium_path() -> str:
    exe = os.environ.get("ANKLE_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
    if not Path(exe).is_file():
        pytest.fail(
            "the browser tests need Debian's chromium: apt-get install -y chromium "
            "(or set ANKLE_CHROMIUM to a chromium binary)"
        )
    return exe


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    # Per module, not per session: while Playwright's sync API is open it keeps an event
    # loop running in this thread, and every later test that calls asyncio.run would fail.
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=chromium_path(), args=CHROMIUM_FLAGS)
        try:
            yield b
        finally:
            b.close()


@pytest.fixture
def context(browser: Browser) -> Iterator[BrowserContext]:
    ctx = browser.new_context(viewport={"width": 1400, "height": 1000}, accept_downloads=True)
    try:
        yield ctx
    finally:
        ctx.close()


@pytest.fixture
def page(context: BrowserContext) -> Iterator[Page]:
    """A page that fails the test on any uncaught script error or console error (but the
    browser's own line for an HTTP error answer, which some tests provoke on purpose)."""
    pg = context.new_page()
    errors: list[str] = []

    def on_console(msg: ConsoleMessage) -> None:
        if msg.type == "error" and not msg.text.startswith("Failed to load resource"):
            errors.append(f"console error: {msg.text}")

    pg.on("pageerror", lambda exc: errors.append(f"page error: {exc}"))
    pg.on("console", on_console)
    pg.set_default_timeout(WAIT_MS)
    yield pg
    assert not errors, "\n".join(errors)


@pytest.fixture(scope="session")
def shots() -> Path:
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    return SCREENSHOTS

"""Helpers for the editor's browser tests (no tests here): the system Chromium, a playwright page on the editor,
polling with a hang guard, and a raw WebSocket client as viser's own."""

from __future__ import annotations

import asyncio
import contextlib
import os
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
IN_CI = os.environ.get("CI", "").lower() == "true"
WAIT_S = 120.0
"""Per-step hang guard, not a timing assumption: every wait polls for a condition and returns as soon as
it holds. On an idle 2-core machine the whole test takes about 15 s; software WebGL (SwiftShader) on a
machine loaded by other processes can take tens of seconds for one frame."""
needs_chromium = pytest.mark.skipif(not IN_CI and not Path(CHROMIUM).is_file(),
                                    reason="Debian chromium is not installed (apt-get install -y chromium); "
                                           "CI installs it and never skips this test")
"""Skip a browser test where no Chromium is installed (never in CI)."""
CHROMIUM_ARGS = ["--no-sandbox", "--enable-unsafe-swiftshader", "--disable-dev-shm-usage"]


def wait_for(condition, what: str, timeout: float = WAIT_S):
    """Poll ``condition()`` until it is truthy (returned) or fail after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(0.2)


def body_pixels(png: bytes) -> int:
    """Pixels of the body's blue-grey colour (blue well above red) in a screenshot."""
    import io

    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return int(((b - r > 25) & (b > 120) & (g > 100)).sum())


@contextlib.contextmanager
def editor_page(url: str, *, width: int = 1100, height: int = 700) -> Iterator[Any]:
    """A playwright page of headless Debian Chromium on the editor at ``url``, its 3D canvas loaded; the browser
    closes on exit."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True, timeout=30_000)
        try:
            page = browser.new_page(viewport={"width": width, "height": height})
            page.set_default_timeout(WAIT_S * 1000)
            page.goto(url)
            page.wait_for_selector("canvas")
            yield page
        finally:
            browser.close()


def ws_attempt(url: str, origin: str | None) -> str:
    """Open a WebSocket as viser's client does (its subprotocol); 'open' when the first message arrives."""
    import viser
    import websockets.asyncio.client as client
    from websockets.exceptions import InvalidStatus

    headers = {} if origin is None else {"Origin": origin}

    async def go() -> str:
        try:
            async with client.connect(url, subprotocols=[f"viser-v{viser.__version__}"], additional_headers=headers,
                                      origin=None, open_timeout=WAIT_S) as ws:
                await asyncio.wait_for(ws.recv(), WAIT_S)
                return "open"
        except InvalidStatus as exc:
            return f"refused {exc.response.status_code}"

    return asyncio.run(go())

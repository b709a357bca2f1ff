"""Headless Chromium for the dashboard's test and benchmark: Debian's ``chromium`` driven by Playwright
(``executable_path``; Playwright never downloads a browser here). Playwright comes with the ``test`` extra."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

CHROMIUM = os.environ.get("QUADSITL_CHROMIUM", "/usr/bin/chromium")
# As root in a container, without a GPU, on a machine with no route out: no sandbox, no GPU, and none of
# Chromium's background connections to Google's hosts.
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-quic"]  # fmt: skip


@contextlib.contextmanager
def chromium() -> Iterator[object]:
    """A Playwright ``Browser`` on Debian's Chromium; RuntimeError if either is missing."""
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        raise RuntimeError("Playwright is not installed: pip install -e '.[test]'") from None
    if not Path(CHROMIUM).exists():
        raise RuntimeError(f"no Chromium at {CHROMIUM}: apt-get install chromium, or set QUADSITL_CHROMIUM")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()

"""Headless Chromium for the dashboard's test and benchmark: Debian's ``chromium`` driven by Playwright
(``executable_path``; Playwright never downloads a browser here). Both are optional for users: Playwright comes
with the ``test`` extra, Chromium from Debian, and ``./scripts/test`` installs both. :func:`missing` says which
one this machine lacks and how to get it, so that ``quadsitl bench`` can skip its dashboard section."""

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


INSTALL_PLAYWRIGHT = "pip install playwright (the test extra has it: ./scripts/test installs it)"
INSTALL_CHROMIUM = "apt-get install chromium (./scripts/test does), or set QUADSITL_CHROMIUM to a Chromium binary"


def missing() -> str | None:
    """What driving the dashboard in a browser needs and this machine lacks, with how to get it (one line);
    None when Playwright imports and Chromium is where :data:`CHROMIUM` says."""
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return f"Playwright is not installed: {INSTALL_PLAYWRIGHT}"
    if not Path(CHROMIUM).exists():
        return f"no Chromium at {CHROMIUM}: {INSTALL_CHROMIUM}"
    return None


@contextlib.contextmanager
def chromium() -> Iterator[object]:
    """A Playwright ``Browser`` on Debian's Chromium; RuntimeError if either is missing."""
    why = missing()
    if why:
        raise RuntimeError(why)
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()

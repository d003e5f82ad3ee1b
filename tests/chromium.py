"""Headless Chromium for the browser tests: Debian's chromium (`make system-deps`) driven by the
Playwright driver (the `test` extra); no browser is downloaded. `playwright()` skips the calling
test (or, at import, the module) where either is missing, instead of failing."""
import os
import shutil
from pathlib import Path

import pytest

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]
ARTIFACTS = Path(os.environ.get("THERMAL4D_ARTIFACTS", Path(__file__).parent / "artifacts"))


def playwright(module_level: bool = False):
    """The playwright.sync_api module, or a skip naming what is missing."""
    sync_api = pytest.importorskip("playwright.sync_api", reason="the Playwright driver is not installed")
    if not os.access(CHROMIUM, os.X_OK):
        pytest.skip(f"no Chromium at {CHROMIUM} (make system-deps installs it)", allow_module_level=module_level)
    return sync_api

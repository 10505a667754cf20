"""Headless Chromium for the report's browser tests (``test_report_browser.py``,
``test_viewer_browser.py``): Debian's ``chromium`` (``make browser-deps``), run as root-safe and
with the background networking this machine's closed network refuses turned off."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

CHROMIUMS = ("chromium", "chromium-browser", "google-chrome")


def find_chromium() -> str | None:
    """The first Chromium on the PATH, or ``None``."""
    return next((p for p in map(shutil.which, CHROMIUMS) if p), None)


def chromium() -> str:
    """The Chromium to run; skips (fails under CI) when there is none."""
    exe = find_chromium()
    if exe is None:
        if os.environ.get("CI", "").lower() in ("true", "1", "yes"):
            pytest.fail("CI is set but no Chromium is installed: run `make browser-deps` as root")
        pytest.skip(f"no headless Chromium ({', '.join(CHROMIUMS)}): apt-get install chromium")
    return exe


def run_chromium(exe: str, profile: Path, *args: str) -> subprocess.CompletedProcess:
    """Run headless ``exe`` with a fresh profile folder and ``args`` (the page last)."""
    cmd = [
        exe,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--hide-scrollbars",
        f"--user-data-dir={profile}",
        *args,
    ]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=180, check=False)

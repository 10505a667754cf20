"""Fixtures of the command-line tests."""

from __future__ import annotations

from pathlib import Path

import pytest
from fast_methods import add_methods, fast_method


@pytest.fixture
def here(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A work folder (the current one for the test) where a 3x3 box method ``box3`` exists."""
    add_methods(monkeypatch, fast_method("box3"))
    monkeypatch.chdir(tmp_path)
    return tmp_path

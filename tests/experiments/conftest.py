"""Fixtures of the experiment tests (helpers live in ``synthetic_data.py``)."""

from __future__ import annotations

import pytest
from synthetic_data import FakeMethods


@pytest.fixture
def fake_methods(monkeypatch: pytest.MonkeyPatch) -> FakeMethods:
    """Fast fake methods registered for one test (removed afterwards), with call counts."""
    return FakeMethods(monkeypatch)

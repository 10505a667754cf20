"""Run the docstring examples of mcdenoise.experiments so they stay true."""

from __future__ import annotations

import doctest
import importlib

import pytest


@pytest.mark.parametrize("name", ["quality", "tradeoff", "stats", "timing", "provenance", "units"])
def test_docstring_examples(name):
    module = importlib.import_module(f"mcdenoise.experiments.{name}")
    failed, attempted = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
    assert attempted > 0 and failed == 0

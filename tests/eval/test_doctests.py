"""Run the docstring examples of mcdenoise.eval so they stay true."""

from __future__ import annotations

import doctest
import importlib

import pytest


@pytest.mark.parametrize("name", ["metrics", "tonemap", "preview", "matching", "noisebase"])
def test_docstring_examples(name):
    module = importlib.import_module(f"mcdenoise.eval.{name}")
    failed, attempted = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
    assert attempted > 0 and failed == 0

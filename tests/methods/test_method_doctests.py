"""The docstring examples of the fixed-filter pipelines run."""

from __future__ import annotations

import doctest

import pytest

import mcdenoise.methods.cross_bilateral
import mcdenoise.methods.nlm


@pytest.mark.parametrize("module", [mcdenoise.methods.cross_bilateral, mcdenoise.methods.nlm])
def test_doctests(module) -> None:
    failed, attempted = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
    assert attempted > 0 and failed == 0

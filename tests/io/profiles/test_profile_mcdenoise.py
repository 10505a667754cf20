"""The ``mcdenoise`` canonical layout (mcdenoise/io/profiles/mcdenoise.py)."""

from __future__ import annotations

import doctest

import pytest

from mcdenoise.errors import InputError
from mcdenoise.io import canonical_channels
from mcdenoise.io.profiles import mcdenoise as canonical


def test_canonical_channel_names():
    assert canonical_channels("color") == ("R", "G", "B")
    assert canonical_channels("normal") == ("normal.X", "normal.Y", "normal.Z")
    assert canonical_channels("depth") == ("depth.Z",)
    assert canonical_channels("visibility") == ("visibility.Y",)
    assert canonical_channels("motion") == ("motion.X", "motion.Y")
    assert canonical_channels("color_var") == ("color_var.R", "color_var.G", "color_var.B")
    assert canonical_channels("color_var", 1) == ("color_var.Y",)
    assert canonical_channels("depth_var") == ("depth_var.Z",)
    with pytest.raises(InputError):
        canonical_channels("albedo", 1)


def test_docstring_examples_run():
    failed, attempted = doctest.testmod(canonical)
    assert attempted > 0 and failed == 0

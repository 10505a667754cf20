"""The docstring examples of the camera reader and the AO package run."""

from __future__ import annotations

import doctest

import pytest

import mcdenoise.ao.geometry
import mcdenoise.io.camera
import mcdenoise.methods.ao


@pytest.mark.parametrize(
    "module", [mcdenoise.io.camera, mcdenoise.ao.geometry, mcdenoise.methods.ao], ids=str
)
def test_doctests(module) -> None:
    failed, _ = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
    assert failed == 0


def test_the_camera_reader_has_examples():
    assert doctest.testmod(mcdenoise.io.camera).attempted >= 2

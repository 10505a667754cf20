"""Shared synthetic data for the filter tests (small, seeded, made in the test run)."""

from __future__ import annotations

import pytest
from noisy_scene import NoisyScene, make_scene, relmse


@pytest.fixture
def scene() -> NoisyScene:
    return make_scene()


@pytest.fixture
def scene_factory():
    """``make_scene(h, w, seed, noise)`` for tests that need other sizes."""
    return make_scene


@pytest.fixture
def rel_mse():
    """The relMSE function (fixtures avoid importing conftest by name)."""
    return relmse

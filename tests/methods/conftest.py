"""The seeded synthetic scene of ``tests/noisy_scene.py`` as a fixture."""

from __future__ import annotations

import pytest
from noisy_scene import NoisyScene, make_scene


@pytest.fixture
def scene() -> NoisyScene:
    return make_scene()

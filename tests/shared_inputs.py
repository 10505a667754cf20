"""Inputs several test packages make the same way (``tests/`` is on ``sys.path`` through its
own conftest): a small render with half buffers, and an installed plugin's entry point."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from mcdenoise.io import FeatureBuffers, save_buffers


def noisy_with_halves(path: Path, size: int = 24) -> Path:
    """A small render with half buffers (what ``render --halves`` writes), made without
    Mitsuba: two independent noisy halves of a step image, their mean and variances."""
    g = torch.Generator().manual_seed(1)
    _y, x = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    mu = (0.2 + 0.6 * (x > size // 2)).float().expand(3, -1, -1)
    a = mu * (1 + 0.5 * torch.randn(3, size, size, generator=g)).clamp_min(0)
    b = mu * (1 + 0.5 * torch.randn(3, size, size, generator=g)).clamp_min(0)
    var = torch.full((3, size, size), 0.02)
    bufs = {"color": (a + b) / 2, "color_var": var / 2, "color_a": a, "color_b": b}
    save_buffers(path, FeatureBuffers(bufs | {"color_a_var": var, "color_b_var": var}, spp=8))
    return path


class EntryPoint:
    """What ``importlib.metadata.entry_points`` yields: ``name``, ``value``, ``load()``
    (which raises ``error`` when given); installed by the ``plugins`` fixture of
    tests/conftest.py."""

    def __init__(self, name: str, value: str, obj: Any = None, error: Exception | None = None):
        self.name, self.value, self._obj, self._error = name, value, obj, error

    def load(self) -> Any:
        if self._error is not None:
            raise self._error
        return self._obj

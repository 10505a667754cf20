"""Fixtures shared by the model tests."""

from __future__ import annotations

import pytest
import torch

import mcdenoise.models.multiscale as multiscale


@pytest.fixture
def kernel_dtypes(monkeypatch) -> list[tuple[torch.dtype, torch.dtype]]:
    """The (image, weights) dtypes of every ``apply_kernels`` call the models make while the
    test runs, in order (the function still runs)."""
    seen: list[tuple[torch.dtype, torch.dtype]] = []
    real = multiscale.apply_kernels

    def spy(image, weights, **kw):
        seen.append((image.dtype, weights.dtype))
        return real(image, weights, **kw)

    monkeypatch.setattr(multiscale, "apply_kernels", spy)
    return seen

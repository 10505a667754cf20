"""Fast stand-in methods for the command-line tests, so what is tested is the command (paths,
streams, progress, checks), not a denoiser's speed on a busy machine."""

from __future__ import annotations

import pytest
import torch
from click.testing import CliRunner, Result
from mcdenoise_cli.main import main

from mcdenoise import registry
from mcdenoise.method import Method


def _box(b, p, d) -> torch.Tensor:
    """3x3 box filter of the colour: (3, H, W) -> (3, H, W)."""
    c = b["color"][None]
    return torch.nn.functional.avg_pool2d(c, 3, 1, 1, count_include_pad=False)[0]


def fast_method(name: str = "box3", requires: tuple[str, ...] = ("color",)) -> Method:
    return Method(name=name, summary="3x3 box", requires=requires, uses=(), defaults={}, run=_box)


def add_methods(monkeypatch: pytest.MonkeyPatch, *methods: Method, only: bool = False) -> None:
    """Register ``methods`` for one test; ``only``: hide every other method (``--method all``)."""
    registry.methods()  # the built-ins first, so they do not come back later
    if only:
        monkeypatch.setattr(registry, "_REGISTRY", {})
    for m in methods:
        monkeypatch.setitem(registry._REGISTRY, m.name, m)


def run_cli(*args: object) -> Result:
    """``mcdenoise ARGS...`` in process (arguments turned into strings), exceptions raised."""
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)

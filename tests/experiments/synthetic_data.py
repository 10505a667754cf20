"""Helpers of the experiment tests: synthetic render folders and fast fake methods.

A *synthetic render folder* has exactly the layout and manifest of ``mcdenoise render``
(``<id>.exr`` with parts ``spp<n>``, ``ref/<id>.exr``, ``manifest.json``) but its pixels are
drawn from a known model, without Mitsuba: the clean image is a smooth positive pattern, the
level of ``n`` spp adds Gaussian noise of variance ``sigma² / n`` (so its expected relMSE
falls exactly as 1/n), and the reference adds noise of variance ``sigma² / ref_spp`` and
records that variance as its ``color_var``. Render seconds are ``n × seconds_per_spp`` plus a
known JIT share on the first level, so the runner's bookkeeping can be checked exactly.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from mcdenoise import registry
from mcdenoise.errors import InputError
from mcdenoise.io import FeatureBuffers, save_buffers, save_buffers_parts
from mcdenoise.registry import Method
from mcdenoise.render.manifest import MANIFEST, MANIFEST_FORMAT, MANIFEST_VERSION

JIT_SECONDS = 0.25


def clean_image(h: int, w: int, phase: float) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    return np.stack(
        [
            0.6 + 0.4 * np.sin(xx / 4.0 + phase),
            0.3 + 0.5 * yy / h,
            0.2 + 0.1 * np.cos((xx + yy) / 6.0),
        ]
    )


def make_render_folder(
    folder: Path,
    *,
    scenes: Sequence[str] = ("alpha", "beta"),
    size: tuple[int, int] = (24, 32),
    spp: Sequence[int] = (1, 2, 4),
    ref_spp: int = 4096,
    sigma: float = 0.3,
    seconds_per_spp: float = 0.01,
    seed: int = 0,
    features: bool = True,
    shard_settings: Mapping[str, Any] | None = None,
) -> Path:
    """Write a synthetic render folder (see the module docstring); return ``folder``."""
    rng = np.random.default_rng(seed)
    h, w = size
    (folder / "ref").mkdir(parents=True, exist_ok=True)
    images = []
    for k, name in enumerate(scenes):
        clean = clean_image(h, w, phase=k)
        parts: dict[str, FeatureBuffers] = {}
        levels = []
        cumulative = 0.0
        previous = 0
        for i, n in enumerate(spp):
            color = clean + rng.normal(0.0, sigma / np.sqrt(n), clean.shape)
            bufs = {
                "color": torch.from_numpy(color.astype(np.float32)),
                "color_var": torch.full((3, h, w), sigma**2 / n),
            }
            if features:
                bufs["albedo"] = torch.full((3, h, w), 0.7)
                bufs["normal"] = torch.stack(
                    [torch.zeros(h, w), torch.zeros(h, w), torch.ones(h, w)]
                )
                bufs["depth"] = torch.full((1, h, w), 2.0)
            parts[f"spp{n}"] = FeatureBuffers(bufs, spp=n)
            jit = JIT_SECONDS if i == 0 else 0.0
            cumulative += (n - previous) * seconds_per_spp + jit
            previous = n
            levels.append(
                {
                    "spp": n,
                    "part": f"spp{n}",
                    "render_seconds": round(cumulative, 6),
                    "jit_seconds": jit,
                }
            )
        save_buffers_parts(folder / f"{name}.exr", parts)
        ref = clean + rng.normal(0.0, sigma / np.sqrt(ref_spp), clean.shape)
        save_buffers(
            folder / "ref" / f"{name}.exr",
            FeatureBuffers(
                {
                    "color": torch.from_numpy(ref.astype(np.float32)),
                    "color_var": torch.full((3, h, w), sigma**2 / ref_spp),
                },
                spp=ref_spp,
            ),
        )
        images.append(
            {
                "id": name,
                "index": k,
                "scene": name,
                "seed": 1000 + k,
                "spec": {"name": name, "synthetic": True, "sigma": sigma},
                "variant": "synthetic",
                "mitsuba_version": "none",
                "files": {"noisy": f"{name}.exr", "reference": f"ref/{name}.exr"},
                "levels": levels,
                "reference": {"spp": ref_spp, "render_seconds": ref_spp * seconds_per_spp},
            }
        )
    settings = {"width": w, "height": h, "spp": list(spp), "ref_spp": ref_spp, "pass_spp": 128}
    manifest = {
        "format": MANIFEST_FORMAT,
        "version": MANIFEST_VERSION,
        "settings": settings,
        "images": images,
    }
    (folder / MANIFEST).write_text(json.dumps(manifest, indent=1), encoding="utf-8")
    if shard_settings is not None:
        shard = {**manifest, "settings": dict(shard_settings), "shard": {"index": 1, "count": 1}}
        (folder / "manifest.shard-1-of-1.json").write_text(json.dumps(shard), encoding="utf-8")
    return folder


def box3(color: torch.Tensor) -> torch.Tensor:
    """3×3 box filter of a ``(3, H, W)`` image with replicated borders."""
    x = torch.nn.functional.pad(color[None], (1, 1, 1, 1), mode="replicate")
    return torch.nn.functional.avg_pool2d(x, 3, stride=1)[0]


class FakeMethods:
    """Registers fast fake methods for one test and counts their calls."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.monkeypatch = monkeypatch
        self.calls: dict[str, int] = {}

    def add(
        self,
        name: str,
        run: Any = None,
        *,
        defaults: Mapping[str, Any] | None = None,
        requires: Sequence[str] = ("color",),
        unavailable: Any = None,
    ) -> str:
        fn = run or (lambda b, p, d: box3(b["color"]))

        def counted(b: FeatureBuffers, p: Mapping[str, Any], d: torch.device) -> torch.Tensor:
            self.calls[name] = self.calls.get(name, 0) + 1
            return fn(b, p, d)

        method = Method(
            name=name,
            summary=f"test method {name}",
            requires=tuple(requires),
            uses=("color_var", "albedo"),
            defaults=dict(defaults or {"strength": 1.0}),
            run=counted,
            unavailable=unavailable or (lambda: None),
        )
        self.monkeypatch.setitem(registry._REGISTRY, name, method)
        return name


def blend(b: FeatureBuffers, p: Mapping[str, Any], d: torch.device) -> torch.Tensor:
    """Box filter mixed with the input by ``strength`` (1 = box filter only)."""
    s = float(p["strength"])
    return s * box3(b["color"]) + (1.0 - s) * b["color"]


def refuse(b: FeatureBuffers, p: Mapping[str, Any], d: torch.device) -> torch.Tensor:
    raise InputError("this method refuses every input")


def write_spec(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path

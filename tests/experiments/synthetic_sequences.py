"""A synthetic render folder of sequences (the layout and manifest of ``mcdenoise render
--frames N``) without Mitsuba, and a cheap temporal fake method.

Frame ``t`` of a sequence is the smooth pattern of :func:`synthetic_data.clean_image`
translated by ``t`` pixels to the right (integer motion, so ``motion = (-1, 0)`` is exact:
the surface at ``p`` was at ``p - (1, 0)`` in the previous frame; the first column has no
previous pixel and is marked invalid). The level of ``n`` spp adds independent Gaussian noise
of variance ``sigma² / n`` per frame; the reference adds ``sigma² / ref_spp``. Render seconds
per frame are ``n × seconds_per_spp`` plus a JIT share on the first level of every frame.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from synthetic_data import JIT_SECONDS

from mcdenoise import registry
from mcdenoise.io import FeatureBuffers, save_buffers, save_buffers_parts
from mcdenoise.registry import Method
from mcdenoise.render.manifest import MANIFEST, MANIFEST_FORMAT, MANIFEST_VERSION


def moving_image(h: int, w: int, phase: float, shift: int) -> np.ndarray:
    """The pattern of scene ``phase`` translated right by ``shift`` pixels."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    xx = xx - shift
    return np.stack(
        [
            0.6 + 0.4 * np.sin(xx / 4.0 + phase),
            0.3 + 0.5 * yy / h,
            0.2 + 0.1 * np.cos((xx + yy) / 6.0),
        ]
    )


def _motion(h: int, w: int, frame: int) -> dict[str, torch.Tensor]:
    motion = torch.zeros(2, h, w)
    valid = torch.zeros(1, h, w)
    if frame > 0:
        motion[0] = -1.0
        valid[:, :, 1:] = 1.0
    return {"motion": motion, "motion_valid": valid}


def make_sequence_folder(
    folder: Path,
    *,
    scenes: Sequence[str] = ("walk",),
    frames: int = 4,
    size: tuple[int, int] = (32, 32),
    spp: Sequence[int] = (2, 8),
    ref_spp: int = 4096,
    sigma: float = 0.3,
    seconds_per_spp: float = 0.01,
    seed: int = 0,
) -> Path:
    """Write a synthetic folder of sequences (see the module docstring); return ``folder``."""
    rng = np.random.default_rng(seed)
    h, w = size
    images = []
    for k, name in enumerate(scenes):
        (folder / name / "ref").mkdir(parents=True, exist_ok=True)
        frame_records = []
        for t in range(frames):
            clean = moving_image(h, w, k, t)
            motion = _motion(h, w, t)
            parts: dict[str, FeatureBuffers] = {}
            levels = []
            cumulative, previous = 0.0, 0
            for i, n in enumerate(spp):
                color = clean + rng.normal(0.0, sigma / np.sqrt(n), clean.shape)
                bufs = {
                    "color": torch.from_numpy(color.astype(np.float32)),
                    "color_var": torch.full((3, h, w), sigma**2 / n),
                    "albedo": torch.full((3, h, w), 0.7),
                    "normal": torch.stack([torch.zeros(h, w), torch.zeros(h, w), torch.ones(h, w)]),
                    "depth": torch.full((1, h, w), 2.0),
                    **motion,
                }
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
            noisy = f"{name}/frame_{t:04d}.exr"
            ref_file = f"{name}/ref/frame_{t:04d}.exr"
            save_buffers_parts(folder / noisy, parts)
            ref = clean + rng.normal(0.0, sigma / np.sqrt(ref_spp), clean.shape)
            save_buffers(
                folder / ref_file,
                FeatureBuffers(
                    {
                        "color": torch.from_numpy(ref.astype(np.float32)),
                        "color_var": torch.full((3, h, w), sigma**2 / ref_spp),
                        **motion,
                    },
                    spp=ref_spp,
                ),
            )
            frame_records.append(
                {
                    "frame": t,
                    "time": t / max(frames - 1, 1),
                    "seed": 5000 + 100 * k + t,
                    "files": {"noisy": noisy, "reference": ref_file},
                    "levels": levels,
                    "reference": {"spp": ref_spp},
                }
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
                "files": {"folder": name},
                "sequence": {"frames": frames},
                "frames": frame_records,
                "complete": True,
            }
        )
    settings = {
        "width": w,
        "height": h,
        "spp": list(spp),
        "ref_spp": ref_spp,
        "pass_spp": 128,
        "frames": frames,
    }
    manifest = {
        "format": MANIFEST_FORMAT,
        "version": MANIFEST_VERSION,
        "settings": settings,
        "images": images,
    }
    (folder / MANIFEST).write_text(json.dumps(manifest, indent=1), encoding="utf-8")
    return folder


def add_running_mean(
    monkeypatch: pytest.MonkeyPatch, calls: dict[str, int], name: str = "running-mean"
) -> str:
    """Register a cheap temporal method: the mean of the frame and the previous output warped
    by the frame's integer motion where ``motion_valid`` is 1 (the input elsewhere). It counts
    the sequences it is given in ``calls[name]``."""

    def run_sequence(
        frames: Iterable[FeatureBuffers], params: Mapping[str, Any], device: torch.device
    ) -> Iterator[torch.Tensor]:
        calls[name] = calls.get(name, 0) + 1
        previous = None
        for f in frames:
            color = f["color"]
            if previous is None or "motion" not in f:
                out = color
            else:
                dx = round(float(f["motion"][0].mean()))
                warped = torch.roll(previous, shifts=-dx, dims=2)
                valid = f["motion_valid"] > 0.5
                out = torch.where(valid, 0.5 * (color + warped), color)
            previous = out
            yield out

    method = Method(
        name=name,
        summary="test: running mean along the motion",
        requires=("color",),
        uses=("motion", "motion_valid"),
        defaults={"strength": 1.0},
        run=None,
        temporal=True,
        run_sequence=run_sequence,
    )
    monkeypatch.setitem(registry._REGISTRY, name, method)
    return name

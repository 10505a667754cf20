"""Helpers for the io tests: tiny synthetic EXR files made at test time (nothing shipped)."""

from __future__ import annotations

import struct
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np
import pytest


def _write_multipart(path: Path, parts: Sequence[Mapping]) -> Path:
    """Write a multi-part EXR with OpenImageIO (the library itself writes single parts only).

    Each part: ``{"name": str, "channels": {name: (H, W) array}, "x": int, "y": int,
    "types": {name: "half"|"float"}}``; every part shares one display window (an OpenEXR rule).
    """
    import OpenImageIO as oiio

    specs, datas = [], []
    full_w = max(p.get("x", 0) + next(iter(p["channels"].values())).shape[1] for p in parts)
    full_h = max(p.get("y", 0) + next(iter(p["channels"].values())).shape[0] for p in parts)
    for p in parts:
        names = list(p["channels"])
        h, w = p["channels"][names[0]].shape
        spec = oiio.ImageSpec(w, h, len(names), "float")
        spec.channelnames = tuple(names)
        types = p.get("types", {})
        spec.channelformats = tuple(oiio.TypeDesc(types.get(n, "float")) for n in names)
        spec.x, spec.y = p.get("x", 0), p.get("y", 0)
        spec.full_x, spec.full_y, spec.full_width, spec.full_height = 0, 0, full_w, full_h
        spec.attribute("name", p["name"])
        spec.attribute("compression", "zip")
        spec.attribute("DateTime", "")
        for k, v in p.get("attributes", {}).items():
            spec.attribute(k, v)
        specs.append(spec)
        datas.append(np.stack([np.asarray(p["channels"][n], np.float32) for n in names], -1))
    out = oiio.ImageOutput.create("openexr")
    assert out.open(str(path), specs), out.geterror()
    for i, (spec, data) in enumerate(zip(specs, datas)):
        if i:
            assert out.open(str(path), spec, "AppendSubimage"), out.geterror()
        assert out.write_image(data), out.geterror()
    assert out.close()
    return path


@pytest.fixture
def write_multipart() -> Callable[[Path, Sequence[Mapping]], Path]:
    return _write_multipart


def _patch_data_window(src: Path, dst: Path, window: tuple[int, int, int, int]) -> Path:
    """Copy ``src`` to ``dst`` with the header's dataWindow replaced (pixels untouched)."""
    data = bytearray(src.read_bytes())
    key = b"dataWindow\x00box2i\x00"
    i = data.index(key) + len(key)
    assert struct.unpack("<i", data[i : i + 4])[0] == 16
    data[i + 4 : i + 20] = struct.pack("<4i", *window)
    dst.write_bytes(bytes(data))
    return dst


@pytest.fixture
def patch_data_window() -> Callable[[Path, Path, tuple[int, int, int, int]], Path]:
    return _patch_data_window


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)

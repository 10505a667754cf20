"""The ``cycles`` profile: Blender multilayer EXR (mcdenoise/io/profiles/cycles.py)."""

from __future__ import annotations

import numpy as np
import pytest
from profile_files import planes, stack, write

from mcdenoise.io import ProfileError, load_buffers


def cycles_channels(rng):
    ch = {}
    for layer in ("Composite", "View Layer.001"):
        ch.update(planes(rng, [f"{layer}.Combined.{c}" for c in "RGBA"]))
    L = "View Layer.001"
    ch.update(planes(rng, [f"{L}.Noisy Image.{c}" for c in "RGBA"]))
    ch.update(planes(rng, [f"{L}.Denoising Albedo.{c}" for c in "RGB"]))
    ch.update(planes(rng, [f"{L}.Denoising Normal.{c}" for c in "XYZ"], -1, 1))
    ch.update(planes(rng, [f"{L}.Denoising Depth.Z", f"{L}.Depth.Z"], 1, 9))
    ch.update(planes(rng, [f"{L}.Position.{c}" for c in "XYZ"], -5, 5))
    ch.update(planes(rng, [f"{L}.Diffuse Color.{c}" for c in "RGB"]))
    return ch


def test_cycles_multilayer(tmp_path, rng):
    ch = cycles_channels(rng)
    attrs = {
        "BlenderMultiChannel": "Blender V2.55.1 and newer",
        "cycles.View Layer.001.samples": "64",
    }
    path = write(tmp_path / "c.exr", ch, attrs)
    fb = load_buffers(path)
    L = "View Layer.001"
    assert fb.profile == f"cycles:{L}" and fb.spp == 64
    assert fb.names() == ["color", "albedo", "normal", "depth", "position"]
    np.testing.assert_array_equal(
        fb["color"].numpy(), stack(ch, [f"{L}.Noisy Image.{c}" for c in "RGB"])
    )
    np.testing.assert_array_equal(fb["depth"].numpy()[0], ch[f"{L}.Denoising Depth.Z"])
    np.testing.assert_array_equal(
        fb["normal"].numpy(), stack(ch, [f"{L}.Denoising Normal.{c}" for c in "XYZ"])
    )
    # Another layer by name: only what it has (its Combined pass).
    comp = load_buffers(path, profile="cycles:Composite")
    assert comp.names() == ["color"]
    np.testing.assert_array_equal(
        comp["color"].numpy(), stack(ch, [f"Composite.Combined.{c}" for c in "RGB"])
    )
    with pytest.raises(ProfileError, match="no Cycles view layer 'Nope'"):
        load_buffers(path, profile="cycles:Nope")

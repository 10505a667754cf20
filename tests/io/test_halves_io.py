"""Half buffers in files: canonical channel names, the Tungsten/KPCN ``<x>A``/``<x>B`` layers,
and the refusals (one half only, halves of another size), each one line naming the buffer."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mcdenoise.errors import InputError
from mcdenoise.io import FeatureBuffers, load_buffers, save_buffers
from mcdenoise.io.buffers import BUFFER_NAMES, HALF_NAMES, check_halves, has_halves
from mcdenoise.io.exr import probe_exr
from mcdenoise.io.exr_write import write_exr
from mcdenoise.io.profiles.mcdenoise import canonical_channels

H, W = 5, 7


def _planes(rng, names, lo=0.0, hi=1.0):
    return {n: rng.uniform(lo, hi, (H, W)).astype(np.float32) for n in names}


def _halved(rng) -> FeatureBuffers:
    a, b = (torch.from_numpy(rng.uniform(0, 2, (3, H, W)).astype(np.float32)) for _ in "ab")
    return FeatureBuffers(
        {
            "color": (a + b) / 2,
            "color_a": a,
            "color_b": b,
            "color_a_var": a * 0.1,
            "color_b_var": b * 0.1,
            "albedo": torch.rand(3, H, W),
            "albedo_a": torch.rand(3, H, W),
            "albedo_b": torch.rand(3, H, W),
        },
        spp=8,
    )


def test_names_and_channels_of_the_halves() -> None:
    assert {"color_a", "color_b", "albedo_a", "depth_b"} <= set(HALF_NAMES)
    assert {"color_a_var", "color_b_var", "albedo_a_var"} <= set(BUFFER_NAMES)
    assert canonical_channels("color_a") == ("color_a.R", "color_a.G", "color_a.B")
    assert canonical_channels("color_b_var") == ("color_b_var.R", "color_b_var.G", "color_b_var.B")
    assert canonical_channels("depth_a") == ("depth_a.Z",)
    assert canonical_channels("normal_b") == ("normal_b.X", "normal_b.Y", "normal_b.Z")
    with pytest.raises(KeyError):
        FeatureBuffers({"motion_a": torch.zeros(2, H, W)})  # motion is never halved


def test_canonical_round_trip_keeps_the_halves_bit_for_bit(tmp_path, rng) -> None:
    fb = _halved(rng)
    save_buffers(tmp_path / "h.exr", fb)
    names = {c.name for c in probe_exr(tmp_path / "h.exr")[0].channels}
    assert {"color_a.R", "color_b.B", "color_a_var.G", "albedo_b.R"} <= names
    back = load_buffers(tmp_path / "h.exr")
    assert set(back.names()) == set(fb.names()) and has_halves(back)
    for n in fb.names():
        assert torch.equal(back[n], fb[n]), n
    assert torch.equal(back["color"], (back["color_a"] + back["color_b"]) / 2)


def test_one_half_only_is_refused_by_name(tmp_path, rng) -> None:
    fb = _halved(rng)
    del fb.buffers["color_b"], fb.buffers["color_b_var"]
    with pytest.raises(InputError, match="color_a without color_b") as e:
        check_halves(fb)
    assert "\n" not in str(e.value)
    save_buffers(tmp_path / "one.exr", fb)
    with pytest.raises(InputError, match=r"one\.exr: color_a without color_b"):
        load_buffers(tmp_path / "one.exr")
    fb = _halved(rng)
    del fb.buffers["albedo_a"]
    with pytest.raises(InputError, match="albedo_b without albedo_a"):
        check_halves(fb)
    fb = _halved(rng)
    del fb.buffers["color_a"], fb.buffers["color_b"], fb.buffers["color_b_var"]
    with pytest.raises(InputError, match="color_a_var without color_a"):
        check_halves(fb)


def test_halves_of_another_size_are_refused_by_name(tmp_path, rng, write_multipart) -> None:
    fb = _halved(rng)
    with pytest.raises(InputError, match="'color_b' is 3x2 but the image is 7x5"):
        fb["color_b"] = torch.zeros(3, 2, 3)
    big = {**_planes(rng, ["R", "G", "B"]), **_planes(rng, ["color_a.R", "color_a.G", "color_a.B"])}
    small = {f"color_b.{c}": np.zeros((3, 4), np.float32) for c in "RGB"}
    path = write_multipart(
        tmp_path / "sizes.exr",
        [{"name": "main", "channels": big}, {"name": "other", "channels": small}],
    )
    with pytest.raises(InputError, match=r"color_a \(part 'main' 7x5.*color_b \(part 'other' 4x3"):
        load_buffers(path, profile="mcdenoise")


def test_tungsten_kpcn_half_layers_are_read_into_the_canonical_halves(tmp_path, rng) -> None:
    ch = _planes(rng, ["R", "G", "B", "colorVariance.Z"])
    for tag in "AB":
        ch.update(_planes(rng, [f"color{tag}.{c}" for c in "RGB"]))
        ch.update(_planes(rng, [f"albedo{tag}.{c}" for c in "RGB"]))
        ch.update(_planes(rng, [f"depth{tag}.Z"], 1, 5))
    ch.update(_planes(rng, ["albedo.R", "albedo.G", "albedo.B", "depth.Z"]))
    write_exr(tmp_path / "k.exr", ch)
    fb = load_buffers(tmp_path / "k.exr")
    assert fb.profile == "tungsten"
    assert {"color_a", "color_b", "albedo_a", "albedo_b", "depth_a", "depth_b"} <= set(fb.names())
    np.testing.assert_array_equal(fb["color_b"][1].numpy(), ch["colorB.G"])
    np.testing.assert_array_equal(fb["depth_a"][0].numpy(), ch["depthA.Z"])
    assert fb.channels["albedo_b"] == ["albedoB.R", "albedoB.G", "albedoB.B"]
    del ch["colorB.R"], ch["colorB.G"], ch["colorB.B"]
    write_exr(tmp_path / "k1.exr", ch)
    with pytest.raises(InputError, match="color_a without color_b"):
        load_buffers(tmp_path / "k1.exr")

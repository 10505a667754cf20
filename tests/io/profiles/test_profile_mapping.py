"""User mapping files (mcdenoise/io/profiles/mapping.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from profile_files import H, W, mitsuba_channels, planes, stack, write

from mcdenoise.io import MissingFeatureError, ProfileError, load_buffers, load_mapping


def test_mapping_file_toml_and_json(tmp_path, rng):
    ch = planes(rng, ["beauty.R", "beauty.G", "beauty.B", "alb.R", "alb.G", "alb.B", "var.Y"])
    path = write(tmp_path / "u.exr", ch)
    (tmp_path / "map.toml").write_text(
        'color = ["beauty.R", "beauty.G", "beauty.B"]\n'
        'albedo = ["alb.R", "alb.G", "alb.B"]\n'
        'color_var = ["var.Y"]\nspp = 8\nvariance = "sample"\n'
    )
    fb = load_buffers(path, mapping=tmp_path / "map.toml")
    assert fb.profile == "mapping" and fb.spp == 8
    np.testing.assert_array_equal(fb["albedo"].numpy(), stack(ch, ["alb.R", "alb.G", "alb.B"]))
    np.testing.assert_allclose(fb["color_var"].numpy()[0], ch["var.Y"] / 8, rtol=1e-6)
    (tmp_path / "map.json").write_text(json.dumps({"color": ["beauty.R", "beauty.G", "beauty.B"]}))
    assert load_buffers(path, mapping=tmp_path / "map.json").names() == ["color"]


def test_mapping_overrides_a_detected_profile(tmp_path, rng):
    ch = mitsuba_channels(rng, np.zeros((3, H, W)))
    ch.update(planes(rng, ["alb2.R", "alb2.G", "alb2.B"]))
    path = write(tmp_path / "m.exr", ch, {"generatedBy": "Mitsuba version 3.9.1"})
    fb = load_buffers(path, mapping={"albedo": ["alb2.R", "alb2.G", "alb2.B"]})
    assert fb.profile == "mitsuba" and fb.channels["albedo"] == ["alb2.R", "alb2.G", "alb2.B"]
    np.testing.assert_array_equal(fb["normal"].numpy(), stack(ch, ["nn.X", "nn.Y", "nn.Z"]))
    with pytest.raises(MissingFeatureError, match=r"mapping needs depth \(z\.A\)"):
        load_buffers(path, mapping={"depth": ["z.A"]})


@pytest.mark.parametrize(
    ("text", "suffix", "words"),
    [
        ('colour = ["R", "G", "B"]', ".toml", "unknown key 'colour'"),
        ('albedo = ["a.R", "a.G"]', ".toml", r"albedo needs 3 channel name\(s\), got 2"),
        ('color_var = ["a", "b"]', ".toml", r"color_var needs 3 or 1 channel"),
        ('color = ["R", "G", "B"]\nspp = 0', ".toml", "spp must be a positive integer"),
        ('color = ["R", "G", "B"]\nvariance = "biased"', ".toml", "variance must be"),
        ('color = "R"', ".toml", "must be a list of channel names"),
        ("color = [", ".toml", "invalid TOML"),
        ('{"color": ["R", "G", "B"],}', ".json", "invalid JSON"),
        ("spp = 4", ".toml", "names no buffer"),
    ],
)
def test_invalid_mapping_files(tmp_path, text, suffix, words):
    path = tmp_path / f"bad{suffix}"
    path.write_text(text)
    with pytest.raises(ProfileError, match=words) as exc:
        load_mapping(path)
    assert str(path) in str(exc.value) and "\n" not in str(exc.value)
    with pytest.raises(ProfileError, match="not found"):
        load_mapping(tmp_path / "missing.toml")

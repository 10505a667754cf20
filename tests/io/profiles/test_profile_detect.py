"""Profile detection and lookup by name (mcdenoise/io/profiles/detect.py)."""

from __future__ import annotations

import pytest

from mcdenoise.io import ProfileError, detect_profile, get_profile


@pytest.mark.parametrize(
    ("channels", "attributes", "expected"),
    [
        (["R", "G", "B", "depth.Z"], {"mcdenoise:layout": "1"}, "mcdenoise"),
        (["R", "G", "B"], {"BlenderMultiChannel": "Blender V2.55.1 and newer"}, "cycles"),
        (["View Layer.Combined.R", "View Layer.Combined.G", "View Layer.Combined.B"], {}, "cycles"),
        (["R", "G", "B", "Albedo.R", "Ns.X", "P.X"], {}, "pbrt"),
        (["R", "G", "B", "Nsx", "Px"], {}, "pbrt"),
        (["R", "G", "B", "colorVariance.Z", "albedo.R"], {}, "tungsten"),
        (["R", "G", "B", "normal.R", "normal.G", "normal.B"], {}, "tungsten"),
        (["R", "G", "B"], {"generatedBy": "Mitsuba version 3.9.1"}, "mitsuba"),
        (["R", "G", "B", "dd.T"], {}, "mitsuba"),
        (["R", "G", "B", "img.m2_path.X"], {}, "mitsuba"),
        (["R", "G", "B", "sh_normal.X"], {}, "mitsuba"),
        (["B", "G", "R"], {}, "mcdenoise"),
    ],
)
def test_detect_profile(channels, attributes, expected):
    assert detect_profile(channels, attributes).name == expected


def test_undetectable_file_names_its_channels():
    with pytest.raises(ProfileError, match=r"cannot tell.*Y, foo\.bar.*profile="):
        detect_profile(["Y", "foo.bar"], {})


def test_get_profile():
    assert get_profile("PBRT").name == "pbrt"
    assert get_profile("cycles:My.Layer").layer == "My.Layer"
    with pytest.raises(ProfileError, match="unknown profile 'vray'"):
        get_profile("vray")
    with pytest.raises(ProfileError, match="takes no option"):
        get_profile("pbrt:x")

"""Resolution of a profile against a file: completeness checks
(mcdenoise/io/profiles/resolve.py)."""

from __future__ import annotations

import pytest
from profile_files import planes, write

from mcdenoise.io import IncompleteFeatureError, MissingFeatureError, load_buffers
from mcdenoise.io.profiles import resolve_channels


# --- completeness (docs/hard-cases.md item 4) -----------------------------------------------------
def test_incomplete_feature_is_an_error_listing_missing_and_present(tmp_path, rng):
    ch = planes(rng, ["R", "G", "B", "albedo.R", "albedo.G", "depth.Z"])
    path = write(tmp_path / "i.exr", ch, {"mcdenoise:layout": "1"})
    with pytest.raises(IncompleteFeatureError) as exc:
        load_buffers(path)
    msg = str(exc.value)
    assert "albedo is incomplete" in msg and "albedo.B" in msg and "albedo.R, albedo.G" in msg
    assert "file channels:" in msg and "depth.Z" in msg and str(path) in msg
    assert isinstance(exc.value, MissingFeatureError) and "\n" not in msg


def test_missing_colour_is_an_error_optional_features_may_be_absent(tmp_path, rng):
    only_features = write(tmp_path / "f.exr", planes(rng, ["albedo.R", "albedo.G", "albedo.B"]))
    with pytest.raises(MissingFeatureError, match=r"missing color.*albedo\.R"):
        load_buffers(only_features, profile="mcdenoise")
    fb = load_buffers(write(tmp_path / "c.exr", planes(rng, "RGB")))
    assert fb.names() == ["color"]
    with pytest.raises(MissingFeatureError, match=r"needs albedo.*file channels: R, G, B"):
        fb.require(["albedo"], needed_by="kpcn")


def test_non_strict_resolution_collects_problems():
    cmap = resolve_channels(["albedo.R", "normal.X"], {}, profile="mcdenoise", strict=False)
    assert len(cmap.problems) == 3  # normal and albedo incomplete, color missing
    assert "color" not in cmap.sources

"""Tests of mcdenoise.io.info.describe (what ``mcdenoise info`` prints; docs/hard-cases.md
item 10)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from mcdenoise.errors import ExrError
from mcdenoise.io import FeatureBuffers, describe, save_buffers
from mcdenoise.io.exr_write import write_exr


@pytest.fixture
def canonical(tmp_path):
    color = torch.ones(3, 4, 5)
    color[0, 0, 0] = float("nan")
    color[1, 1, 1] = float("inf")
    color[2, 2, 2] = -2.0
    color[2, 3, 3] = -3.0
    fb = FeatureBuffers(
        {
            "color": color,
            "albedo": torch.full((3, 4, 5), 0.5),
            "depth": torch.arange(20.0).view(1, 4, 5),
        },
        spp=8,
        data_window=(2, 3, 6, 6),
        display_window=(0, 0, 9, 9),
    )
    path = tmp_path / "c.exr"
    save_buffers(path, fb, half=["albedo"])
    return path


def test_describe_reports_buffers_counts_and_windows(canonical):
    info = describe(canonical)
    assert info.ok and info.profile == "mcdenoise" and "mcdenoise:layout" in info.profile_reason
    assert (info.width, info.height) == (5, 4)
    assert info.data_window == (2, 3, 6, 6) and info.display_window == (0, 0, 9, 9)
    assert info.spp == 8 and "mcdenoise:spp" in info.spp_source
    by = {b.name: b for b in info.buffers}
    assert list(by) == ["color", "albedo", "depth"]
    c = by["color"]
    assert (c.nan, c.inf, c.negative) == (1, 1, 2)
    assert (c.min, c.max) == (-3.0, 1.0) and c.shape == (3, 4, 5)
    assert c.channels == ["R", "G", "B"] and c.pixel_types == ["float"] * 3
    assert by["albedo"].pixel_types == ["half"] * 3
    assert (by["depth"].nan, by["depth"].inf, by["depth"].negative) == (0, 0, 0)
    assert "normal" in info.missing and "color_var" in info.missing and "color" not in info.missing
    assert info.unmapped == [] and info.problems == []


def test_to_dict_is_strict_json_and_text_mentions_everything(canonical):
    info = describe(canonical)
    d = info.to_dict()
    text = json.dumps(d, allow_nan=False)  # no bare NaN/Infinity
    assert json.loads(text)["buffers"][0]["nan"] == 1
    assert d["parts"][0]["channels"][0] == {"name": "R", "pixel_type": "float"}
    assert d["data_window"] == [2, 3, 6, 6] and d["ok"] is True
    out = info.format_text()
    for words in ("profile     mcdenoise", "data window (2,3)-(6,6)", "display window (0,0)-(9,9)",
                  "spp         8", "color ", "nan 1 inf 1 neg 2", "missing     normal"):  # fmt: skip
        assert words in out, words


def test_describe_does_not_stop_at_an_incomplete_feature(tmp_path):
    ch = {n: np.zeros((3, 3), np.float32) for n in ["R", "G", "B", "albedo.R", "extra.Q"]}
    write_exr(tmp_path / "i.exr", ch, attributes={"mcdenoise:layout": "1"})
    info = describe(tmp_path / "i.exr")
    assert not info.ok
    assert len(info.problems) == 1 and "albedo is incomplete" in info.problems[0]
    assert [b.name for b in info.buffers] == ["color"]
    assert "extra.Q" in info.unmapped and "PROBLEM" in info.format_text()


def test_describe_undetectable_file_lists_its_channels(tmp_path):
    write_exr(tmp_path / "u.exr", {"Y": np.zeros((2, 2), np.float32)})
    info = describe(tmp_path / "u.exr")
    assert info.profile is None and not info.ok
    assert info.unmapped == ["Y"] and "cannot tell" in info.problems[0]


def test_describe_raises_for_unreadable_files(tmp_path):
    (tmp_path / "e.exr").write_bytes(b"")
    with pytest.raises(ExrError, match="is empty"):
        describe(tmp_path / "e.exr")

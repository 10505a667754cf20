"""Multi-part EXR writing: ``write_exr_parts`` and ``save_buffers_parts`` (docs/hard-cases.md
items 9, 11, 12)."""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch

from mcdenoise.errors import ExrError, InputError
from mcdenoise.io import (
    ExrPartData,
    FeatureBuffers,
    load_buffers,
    probe_exr,
    read_exr,
    save_buffers_parts,
    write_exr_parts,
)
from mcdenoise.io.exr_write import HALF_MAX


def _rgb(rng: np.random.Generator, h: int = 5, w: int = 7, scale: float = 1.0) -> dict:
    return {c: (rng.random((h, w)) * scale).astype(np.float32) for c in "RGB"}


def test_parts_round_trip_bit_exact_with_their_own_attributes(tmp_path, rng) -> None:
    a, b = _rgb(rng), {**_rgb(rng), "depth.Z": rng.random((5, 7)).astype(np.float32)}
    path = tmp_path / "p.exr"
    reports = write_exr_parts(
        path,
        [
            ExrPartData("low", a, attributes={"mcdenoise:spp": 4, "note": "first"}),
            ExrPartData("high", b, pixel_type={"depth.Z": "half"}, attributes={"x": 1.5}),
        ],
    )
    assert [r.channels.get("depth.Z") for r in reports] == [None, "half"]
    parts = probe_exr(path)
    assert [p.name for p in parts] == ["low", "high"]
    assert parts[0].attributes["mcdenoise:spp"] == 4 and parts[0].attributes["note"] == "first"
    assert parts[1].attributes["x"] == 1.5 and "note" not in parts[1].attributes
    assert parts[1].pixel_type("depth.Z") == "half" and parts[1].pixel_type("R") == "float"
    for name, data in (("low", a), ("high", b)):
        got = read_exr(path, part=name).pixels
        assert got.keys() == data.keys()
        for c, arr in data.items():
            want = arr.astype(np.float16).astype(np.float32) if c == "depth.Z" else arr
            assert np.array_equal(got[c], want), (name, c)
    # Deterministic bytes: writing the same parts again gives the same file.
    first = path.read_bytes()
    write_exr_parts(path, [ExrPartData("low", a, attributes={"mcdenoise:spp": 4, "note": "first"}),
                           ExrPartData("high", b, pixel_type={"depth.Z": "half"},
                                       attributes={"x": 1.5})])  # fmt: skip
    assert path.read_bytes() == first


def test_half_overflow_is_clamped_and_counted_per_part(tmp_path) -> None:
    big = {"Y": np.full((2, 2), 1e6, np.float32)}
    reports = write_exr_parts(
        tmp_path / "h.exr",
        [ExrPartData("f", big), ExrPartData("h", big, pixel_type="half")],
    )
    assert reports[0].clamped == {} and reports[1].clamped == {"Y": 4}
    assert read_exr(tmp_path / "h.exr", part="h").pixels["Y"].max() == HALF_MAX
    assert read_exr(tmp_path / "h.exr", part="f").pixels["Y"].max() == 1e6


@pytest.mark.parametrize(
    ("parts", "match"),
    [
        ([], "non-empty sequence"),
        ([ExrPartData("", {"Y": np.zeros((2, 2))})], "needs a non-empty name"),
        ([ExrPartData("a", {"Y": np.zeros((2, 2))})] * 2, "'a' is used twice"),
        ([ExrPartData("a", {"Y": np.zeros((2, 2))}, attributes={"name": "b"})], "ExrPartData.name"),
        ([ExrPartData("a", {"Y": np.zeros(3)})], r"part 'a': channel 'Y' must be a 2-D array"),
        (
            [
                ExrPartData("a", {"Y": np.zeros((2, 2))}),
                ExrPartData("b", {"Y": np.zeros((3, 3))}),
            ],
            "display window",
        ),
    ],
)
def test_bad_parts_are_refused_and_nothing_is_written(tmp_path, parts, match) -> None:
    with pytest.raises(InputError, match=match):
        write_exr_parts(tmp_path / "x.exr", parts)
    assert os.listdir(tmp_path) == []


def test_unwritable_destination_leaves_no_file(tmp_path) -> None:
    with pytest.raises(ExrError, match="missing-folder"):
        write_exr_parts(tmp_path / "missing-folder" / "x.exr", [ExrPartData("a", {"Y": np.ones((2, 2))})])  # fmt: skip
    (tmp_path / "d.exr").mkdir()
    with pytest.raises(ExrError, match="is a folder"):
        write_exr_parts(tmp_path / "d.exr", [ExrPartData("a", {"Y": np.ones((2, 2))})])


def _buffers(rng: np.random.Generator, spp: int) -> FeatureBuffers:
    color = torch.from_numpy(rng.random((3, 6, 4)).astype(np.float32))
    return FeatureBuffers(
        {
            "color": color,
            "color_var": color / spp,
            "depth": torch.from_numpy(rng.random((1, 6, 4)).astype(np.float32)),
        },
        spp=spp,
    )


def test_levels_as_parts_load_by_name_and_default_to_the_first(tmp_path, rng) -> None:
    levels = {f"spp{n}": _buffers(rng, n) for n in (4, 16, 64)}
    path = tmp_path / "img.exr"
    save_buffers_parts(
        path,
        levels,
        attributes={"mcdenoise:scene": "s"},
        part_attributes={"spp16": {"mcdenoise:render_seconds": 2.5}},
    )
    for name, fb in levels.items():
        got = load_buffers(path, part=name)
        assert got.names() == ["color", "depth", "color_var"]
        assert got.spp == fb.spp and got.attributes["mcdenoise:scene"] == "s"
        assert all(torch.equal(got[n], fb[n]) for n in fb.names())
    assert load_buffers(path, part="spp16").attributes["mcdenoise:render_seconds"] == 2.5
    assert "mcdenoise:render_seconds" not in load_buffers(path, part="spp4").attributes
    default = load_buffers(path)  # every part is a complete image: the first one
    assert default.spp == 4 and torch.equal(default["color"], levels["spp4"]["color"])


def test_save_buffers_parts_refuses_bad_input(tmp_path, rng) -> None:
    with pytest.raises(InputError, match="no parts"):
        save_buffers_parts(tmp_path / "a.exr", {})
    with pytest.raises(InputError, match="unknown part"):
        save_buffers_parts(tmp_path / "a.exr", {"a": _buffers(rng, 4)}, part_attributes={"b": {}})
    with pytest.raises(InputError, match=r"part 'e': .*no buffers"):
        save_buffers_parts(tmp_path / "a.exr", {"a": _buffers(rng, 4), "e": FeatureBuffers()})
    assert os.listdir(tmp_path) == []

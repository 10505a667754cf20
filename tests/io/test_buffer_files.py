"""Tests of mcdenoise.io.buffer_files: load_buffers / save_buffers (docs/hard-cases.md items
4-6, 9-11)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mcdenoise.errors import ExrError, InputError
from mcdenoise.io import FeatureBuffers, load_buffers, probe_exr, save_buffers
from mcdenoise.io.exr import read_exr
from mcdenoise.io.exr_write import write_exr


def full_buffers(rng: np.random.Generator, h: int = 13, w: int = 21) -> FeatureBuffers:
    """Every buffer, 3- and 1-channel variances, random values incl. negatives where valid."""

    def t(c: int, lo: float = 0.0, hi: float = 1.0) -> torch.Tensor:
        return torch.from_numpy(rng.uniform(lo, hi, (c, h, w)).astype(np.float32))

    return FeatureBuffers(
        {
            "color": t(3, 0, 50),
            "albedo": t(3),
            "normal": t(3, -1, 1),
            "depth": t(1, 1, 9),
            "position": t(3, -5, 5),
            "diffuse": t(3),
            "specular": t(3),
            "visibility": t(1),
            "motion": t(2, -3, 3),
            "color_var": t(1, 0, 0.1),
            "albedo_var": t(3, 0, 0.1),
            "depth_var": t(1, 0, 0.1),
            "motion_var": t(2, 0, 0.1),
        },
        spp=32,
    )


def test_save_load_round_trip_is_exact(tmp_path, rng):
    fb = full_buffers(rng)
    report = save_buffers(tmp_path / "a.exr", fb)
    assert report.clamped == {} and set(report.channels.values()) == {"float"}
    names = set(probe_exr(tmp_path / "a.exr")[0].channel_names)
    assert {"R", "G", "B", "depth.Z", "visibility.Y", "motion.X", "color_var.Y",
            "albedo_var.B", "depth_var.Z", "motion_var.Y"} <= names  # fmt: skip
    back = load_buffers(tmp_path / "a.exr")
    assert back.profile == "mcdenoise" and back.spp == 32
    assert back.names() == fb.names()
    for n in fb.names():
        assert back[n].dtype == torch.float32
        assert torch.equal(back[n], fb[n]), n
    assert back.channels["color_var"] == ["color_var.Y"]
    assert back.attributes["mcdenoise:layout"] == "1" and back.attributes["mcdenoise:spp"] == 32
    assert set(back.attributes["_file_channels"]) == names
    assert back.source == str(tmp_path / "a.exr")


def test_half_output_equals_half_values_and_reports_clamping(tmp_path, rng):
    fb = full_buffers(rng)
    fb["color"][0, 0, 0] = 1e6
    fb["color"][1, 0, 0] = float("inf")
    report = save_buffers(tmp_path / "h.exr", fb, half=["color", "albedo"])
    assert report.clamped == {"R": 1}
    assert report.channels["R"] == "half" and report.channels["normal.X"] == "float"
    back = load_buffers(tmp_path / "h.exr")
    with np.errstate(over="ignore"):
        want = fb["color"].numpy().astype(np.float16).astype(np.float32)
    want[0, 0, 0] = 65504.0
    assert np.array_equal(back["color"].numpy(), want)
    assert back["color"][1, 0, 0] == float("inf")
    assert torch.equal(back["normal"], fb["normal"])
    with pytest.raises(InputError, match="not present: specular_var"):
        save_buffers(tmp_path / "x.exr", fb, half=["specular_var"])


def test_nan_inf_negative_are_loaded_as_they_are(tmp_path, rng):
    fb = full_buffers(rng)
    fb["color"][0, 1, 1] = float("nan")
    fb["color"][2, 2, 2] = float("-inf")
    fb["color"][1, 3, 3] = -4.0
    save_buffers(tmp_path / "n.exr", fb)
    back = load_buffers(tmp_path / "n.exr")
    c = back["color"]
    assert torch.isnan(c[0, 1, 1]) and c[2, 2, 2] == float("-inf") and c[1, 3, 3] == -4.0
    counts = back.nonfinite_counts()["color"]
    assert counts == {"nan": 1, "inf": 1, "negative": 2}  # -inf counts as negative too


def test_windows_survive_round_trip_with_negative_origin(tmp_path, rng):
    fb = full_buffers(rng, h=5, w=7)
    fb.data_window = (-3, -2, 3, 2)
    fb.display_window = (0, 0, 63, 31)
    save_buffers(tmp_path / "w.exr", fb)
    back = load_buffers(tmp_path / "w.exr")
    assert back.data_window == (-3, -2, 3, 2) and back.display_window == (0, 0, 63, 31)
    assert torch.equal(back["color"], fb["color"])
    save_buffers(tmp_path / "w2.exr", back)  # read -> write -> read
    again = load_buffers(tmp_path / "w2.exr")
    assert (again.data_window, again.display_window) == (back.data_window, back.display_window)


def test_crop_moves_the_data_window(tmp_path, rng):
    fb = full_buffers(rng, h=10, w=12)
    fb.data_window = (100, 200, 111, 209)
    fb.display_window = (0, 0, 499, 499)
    crop = fb.crop(3, 4, 5, 6)
    assert crop.data_window == (104, 203, 109, 207)
    save_buffers(tmp_path / "c.exr", crop)
    back = load_buffers(tmp_path / "c.exr")
    assert back.data_window == (104, 203, 109, 207) and back.display_window == (0, 0, 499, 499)
    assert torch.equal(back["color"], fb["color"][:, 3:8, 4:10])
    stale = fb.crop(0, 0, 4, 4)
    stale.data_window = fb.data_window
    with pytest.raises(InputError, match="data_window"):
        save_buffers(tmp_path / "s.exr", stale)


def test_tiled_repeats_every_buffer_keeps_metadata_and_drops_the_windows(tmp_path, rng):
    fb = full_buffers(rng, h=10, w=12)
    fb.spp = 4
    fb.data_window = (100, 200, 111, 209)
    big = fb.tiled(25, 30)
    assert big.shape == (25, 30) and big.spp == 4 and big.names() == fb.names()
    assert big.data_window is None and big.display_window is None
    assert torch.equal(big["color"][:, 10:20, 12:24], fb["color"])
    assert torch.equal(big["depth"][:, 20:25, 24:30], fb["depth"][:, :5, :6])
    save_buffers(tmp_path / "t.exr", big)  # writable: no stale window
    assert load_buffers(tmp_path / "t.exr").shape == (25, 30)


def test_multipart_channels_by_name_and_part_selection(tmp_path, rng, write_multipart):
    r = {c: rng.random((4, 6)).astype(np.float32) for c in "RGB"}
    a = {f"albedo.{c}": rng.random((4, 6)).astype(np.float32) for c in "RGB"}
    path = write_multipart(
        tmp_path / "mp.exr",
        [
            {"name": "beauty", "channels": r, "attributes": {"mcdenoise:layout": "1"}},
            {"name": "aux", "channels": a},
        ],
    )
    fb = load_buffers(path)  # part=None: channels are found in every part
    assert fb.names() == ["color", "albedo"]
    assert np.array_equal(fb["albedo"].numpy(), np.stack([a[f"albedo.{c}"] for c in "RGB"]))
    only = load_buffers(path, part="beauty")
    assert only.names() == ["color"]
    with pytest.raises(ExrError, match="no part named 'x'"):
        load_buffers(path, part="x")


def test_parts_of_different_size_are_never_broadcast(tmp_path, rng, write_multipart):
    path = write_multipart(
        tmp_path / "mp.exr",
        [
            {"name": "beauty", "channels": {c: np.ones((8, 8)) for c in "RGB"}},
            {"name": "aux", "channels": {"depth.Z": np.ones((4, 4))}},
        ],
    )
    with pytest.raises(ExrError, match=r"different data windows.*'beauty' 8x8.*'aux' 4x4"):
        load_buffers(path, profile="mcdenoise")
    assert load_buffers(path, part="beauty").names() == ["color"]


def test_same_channel_in_two_parts_needs_part(tmp_path, write_multipart):
    rgb = {c: np.ones((3, 3)) for c in "RGB"}
    path = write_multipart(
        tmp_path / "mp.exr", [{"name": "left", "channels": rgb}, {"name": "right", "channels": rgb}]
    )
    with pytest.raises(ExrError, match=r"channel 'R' exists in parts 'left', 'right'.*part="):
        load_buffers(path)
    assert load_buffers(path, part="right").names() == ["color"]


def test_feature_of_other_resolution_than_colour_is_refused():
    # Inside one part every channel shares the data window; FeatureBuffers refuses mixes.
    fb = FeatureBuffers({"color": torch.zeros(3, 8, 8)})
    with pytest.raises(InputError, match="same resolution"):
        fb["albedo"] = torch.zeros(3, 4, 4)


def test_save_is_atomic_and_keeps_windows_from_the_loaded_file(tmp_path, rng):
    src = tmp_path / "in.exr"
    write_exr(src, {c: rng.random((6, 9)).astype(np.float32) for c in "RGB"},
              data_window=(10, 20, 18, 25), display_window=(0, 0, 99, 99))  # fmt: skip
    fb = load_buffers(src)
    save_buffers(src, fb, attributes={"mcdenoise:method": "identity"})  # output = input path
    img = read_exr(src)
    assert img.data_window == (10, 20, 18, 25) and img.display_window == (0, 0, 99, 99)
    assert img.part.attributes["mcdenoise:method"] == "identity"
    assert [p.name for p in tmp_path.iterdir()] == ["in.exr"]


def test_save_rejects_bad_arguments(tmp_path):
    with pytest.raises(InputError, match="no buffers"):
        save_buffers(tmp_path / "e.exr", FeatureBuffers())
    fb = FeatureBuffers({"color": torch.zeros(3, 2, 2)}, spp=4)
    with pytest.raises(InputError, match="contradicts"):
        save_buffers(tmp_path / "e.exr", fb, attributes={"mcdenoise:spp": 8})
    with pytest.raises(InputError, match="set by save_buffers"):
        save_buffers(tmp_path / "e.exr", fb, attributes={"mcdenoise:layout": "2"})
    assert not (tmp_path / "e.exr").exists()

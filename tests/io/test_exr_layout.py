"""The EXR byte layout read directly (``mcdenoise/io/exr_layout.py``): a complete file of any
layout the tool writes is judged complete, every cut one is not (docs/hard-cases.md, the
full-disk case), and header strings are read without OpenImageIO."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from mcdenoise.errors import ExrError
from mcdenoise.io.exr_layout import check_complete, header_strings
from mcdenoise.io.exr_write import ExrPartData, write_exr, write_exr_parts

SAMPLES = Path(__file__).resolve().parents[2] / "data" / "samples"


def cuts(data: bytes) -> list[int]:
    """Lengths to cut a file to: inside its last chunk, its offset table and its header."""
    return sorted({len(data) - 1, len(data) - 37, len(data) // 2, 600, 40, 9})


LAYOUTS = [
    *itertools.product(
        ["none", "rle", "zips", "zip", "piz", "pxr24", "b44", "dwaa", "dwab"],
        [None, (16, 16), (32, 8)],
        ["increasing", "decreasing"],
    ),
    ("zip", (8, 8), "random"),
]


@pytest.mark.parametrize(("compression", "tile", "order"), LAYOUTS)
def test_complete_files_pass_and_every_cut_fails(tmp_path, compression, tile, order):
    rng = np.random.default_rng(0)
    a = rng.random((89, 257)).astype(np.float32)
    p = tmp_path / "x.exr"
    write_exr(
        p, {"R": a, "G": a, "B": a}, compression=compression, tile_size=tile, line_order=order
    )
    check_complete(p)
    data = p.read_bytes()
    for n in cuts(data):
        p.write_bytes(data[:n])
        with pytest.raises(ExrError, match=r"incomplete|unreadable"):
            check_complete(p)


@pytest.mark.parametrize("compression", ["zip", "none", "piz"])
def test_multipart_files_pass_and_every_cut_fails(tmp_path, compression):
    a = np.random.default_rng(1).random((40, 50)).astype(np.float32)
    p = tmp_path / "mp.exr"
    parts = [ExrPartData("spp4", {"R": a, "G": a}), ExrPartData("spp16", {"R": 2 * a, "G": a})]
    write_exr_parts(p, parts, compression=compression)
    check_complete(p)
    data = p.read_bytes()
    for n in cuts(data):
        p.write_bytes(data[:n])
        with pytest.raises(ExrError):
            check_complete(p)


def test_an_unfilled_offset_table_fails(tmp_path):
    """OpenEXR writes the offset table last: a file whose table was never filled in has the
    right size and still lacks its chunks."""
    p = tmp_path / "x.exr"
    write_exr(p, {"Y": np.ones((32, 32), np.float32)}, compression="none")
    data = bytearray(p.read_bytes())
    table = len(data) - 32 * 8 - 32 * (8 + 32 * 4)  # 32 offsets, then 32 one-line chunks
    data[table : table + 8] = bytes(8)
    p.write_bytes(bytes(data))
    with pytest.raises(ExrError, match="offset table"):
        check_complete(p)


def test_shipped_samples_are_complete():
    files = sorted(SAMPLES.rglob("*.exr"))
    assert files
    for f in files:
        check_complete(f)


def test_header_strings_name_the_tools_attributes(tmp_path):
    p = tmp_path / "o.exr"
    write_exr(p, {"Y": np.zeros((4, 4), np.float32)}, attributes={"mcdenoise:method": "nlm"})
    assert header_strings(p)[0]["mcdenoise:method"] == "nlm"
    assert "mcdenoise:method" not in header_strings(SAMPLES / "cornell_spp4.exr")[0]
    (tmp_path / "png.exr").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100))
    with pytest.raises(ExrError, match=r"png\.exr"):
        header_strings(tmp_path / "png.exr")

"""OIDN's training-data layout (issue 26 item 3, ``mcdenoise/io/oidn_layout.py``): a render
folder written in it has the names OIDN's toolkit reads (``doc/training.md``'s regular
expression), one three-channel feature per file; reading it back gives the same pixels; the
layout's rules (reference by name or by most samples, subfolders, zero-padded spp) hold."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch

from mcdenoise.errors import InputError
from mcdenoise.io import FeatureBuffers, load_buffers, save_buffers, save_buffers_parts
from mcdenoise.io.exr import probe_exr
from mcdenoise.io.exr_write import write_exr
from mcdenoise.io.oidn_layout import (
    find_oidn_images,
    read_oidn_level,
    write_oidn_layout,
)

#: The file-name pattern of OIDN's doc/training.md, as printed there.
OIDN_DOC_REGEX = re.compile(r".+_([0-9]+(spp)?|ref|reference|gt|target)\.(hdr|ldr|alb|nrm)\.exr")


def render_folder(folder: Path, ids=("alpha", "beta"), spp=(1, 4), size=(6, 8)) -> Path:
    """A render folder as `mcdenoise render` writes it (parts spp<n>, ref/, manifest.json)."""
    rng = np.random.default_rng(3)
    h, w = size
    (folder / "ref").mkdir(parents=True)
    images = []
    for image_id in ids:
        parts = {}
        for n in spp:
            bufs = {
                "color": torch.from_numpy(rng.random((3, h, w), dtype=np.float32) * 4),
                "color_var": torch.full((3, h, w), 0.1 / n),
                "albedo": torch.from_numpy(rng.random((3, h, w), dtype=np.float32)),
                "normal": torch.nn.functional.normalize(torch.randn(3, h, w), dim=0),
                "depth": torch.full((1, h, w), 2.0),
            }
            parts[f"spp{n}"] = FeatureBuffers(bufs, spp=n)
        save_buffers_parts(folder / f"{image_id}.exr", parts)
        ref = {"color": torch.from_numpy(rng.random((3, h, w), dtype=np.float32))}
        ref["albedo"] = parts[f"spp{spp[-1]}"]["albedo"]
        save_buffers(folder / "ref" / f"{image_id}.exr", FeatureBuffers(ref, spp=1024))
        levels = [{"spp": n, "part": f"spp{n}", "render_seconds": 0.1 * n} for n in spp]
        images.append(
            {
                "id": image_id,
                "files": {"noisy": f"{image_id}.exr", "reference": f"ref/{image_id}.exr"},
                "levels": levels,
            }
        )
    manifest = {"settings": {"spp": list(spp), "ref_spp": 1024}, "images": images}
    (folder / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")
    return folder


def test_a_render_folder_round_trips_through_the_oidn_layout(tmp_path):
    src = render_folder(tmp_path / "render")
    written = write_oidn_layout(src, tmp_path / "oidn")
    names = sorted(p.name for p in written)
    assert names == sorted(
        [
            f"{i}_{n:04d}spp.{f}.exr"
            for i in ("alpha", "beta")
            for n in (1, 4)
            for f in ("hdr", "alb", "nrm")
        ]
        + [f"{i}_ref.{f}.exr" for i in ("alpha", "beta") for f in ("hdr", "alb")]
    )
    for p in written:  # what OIDN's toolkit reads: its names, one 3-channel feature per file
        assert OIDN_DOC_REGEX.fullmatch(p.name)
        (part,) = probe_exr(p)
        assert sorted(part.channel_names) == ["B", "G", "R"]

    images = find_oidn_images(tmp_path / "oidn")
    assert [(im.id, sorted(im.levels)) for im in images] == [("alpha", [1, 4]), ("beta", [1, 4])]
    for im in images:
        for spp, path in im.levels.items():
            back = read_oidn_level(path)
            orig = load_buffers(src / f"{im.id}.exr", part=f"spp{spp}")
            assert back.spp == spp and sorted(back.names()) == ["albedo", "color", "normal"]
            for name in ("color", "albedo", "normal"):
                assert torch.equal(back[name], orig[name]), name
        ref = read_oidn_level(im.reference)
        assert ref.spp is None and sorted(ref.names()) == ["albedo", "color"]
        assert torch.equal(ref["color"], load_buffers(src / "ref" / f"{im.id}.exr")["color"])


def rgb_file(path: Path, value: float = 1.0, channels=("R", "G", "B")) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_exr(path, {c: np.full((2, 3), value, np.float32) for c in channels})


def test_the_layout_rules_of_oidns_toolkit(tmp_path):
    root = tmp_path / "train"
    # scene1/view1: no explicit reference, the most samples (8192) is the reference
    for n in ("0001", "0004", "8192"):
        rgb_file(root / "scene1" / f"view1_{n}.hdr.exr")
        rgb_file(root / "scene1" / f"view1_{n}.alb.exr", 0.5)
    # scene2: zero-padded spp with the 'spp' suffix and an explicit reference
    for tag in ("000008spp", "000064spp", "reference"):
        rgb_file(root / f"scene2_{tag}.hdr.exr")
    rgb_file(root / "scene2_0016.ldr.exr")  # LDR colour: not read
    images = {im.id: im for im in find_oidn_images(root)}
    assert sorted(images) == ["scene1/view1", "scene2"]
    assert sorted(images["scene1/view1"].levels) == [1, 4]
    assert images["scene1/view1"].reference.name == "view1_8192.hdr.exr"
    assert sorted(images["scene2"].levels) == [8, 64]
    assert images["scene2"].reference.name == "scene2_reference.hdr.exr"
    level = read_oidn_level(images["scene1/view1"].levels[4])
    assert level.spp == 4 and float(level["albedo"].mean()) == 0.5


def test_bad_oidn_sets_are_refused_by_name(tmp_path):
    with pytest.raises(InputError, match="no OIDN colour file"):
        find_oidn_images(tmp_path)
    rgb_file(tmp_path / "a" / "x_0004spp.hdr.exr")
    with pytest.raises(InputError, match="'x' has no noisy version and a reference"):
        find_oidn_images(tmp_path / "a")
    rgb_file(tmp_path / "a" / "x_4spp.hdr.exr")
    with pytest.raises(InputError, match="two files of 4 spp"):
        find_oidn_images(tmp_path / "a")
    rgb_file(tmp_path / "b" / "y_0004spp.hdr.exr", channels=("X", "Y", "Z", "W"))
    with pytest.raises(InputError, match="holds three channels"):
        read_oidn_level(tmp_path / "b" / "y_0004spp.hdr.exr")
    with pytest.raises(InputError, match=r"no manifest\.json"):
        write_oidn_layout(tmp_path / "b", tmp_path / "out")


def test_oidns_own_reader_sees_the_written_set(tmp_path):
    """What OIDN's training/dataset.py does with a set (read in its source, not run here): it
    groups ``<dir>/**/*.*.exr`` by the name before the last ``_<spp|ref|...>``, takes the
    last name of a group in sorted order as the target, and reads each feature with
    OpenImageIO's ``read_image(chbegin=0, chend=3, format=FLOAT)``. On the written set the
    target is the ``_ref`` version and the first three channels are the pixels."""
    oiio = pytest.importorskip("OpenImageIO")
    src = render_folder(tmp_path / "render", ids=("alpha",), spp=(4, 16))
    write_oidn_layout(src, tmp_path / "oidn")
    names = sorted({p.name.split(".")[0] for p in (tmp_path / "oidn").glob("*.*.exr")})
    assert names == ["alpha_0004spp", "alpha_0016spp", "alpha_ref"]  # the last is the target
    for stem, part in (("alpha_0004spp", "spp4"), ("alpha_0016spp", "spp16")):
        orig = load_buffers(src / "alpha.exr", part=part)
        for feature, buffer in (("hdr", "color"), ("alb", "albedo"), ("nrm", "normal")):
            inp = oiio.ImageInput.open(str(tmp_path / "oidn" / f"{stem}.{feature}.exr"))
            hwc = inp.read_image(subimage=0, miplevel=0, chbegin=0, chend=3, format=oiio.FLOAT)
            inp.close()
            assert np.array_equal(np.moveaxis(hwc, -1, 0), orig[buffer].numpy()), (stem, feature)


def test_train_reads_the_written_set_like_the_render_folder(tmp_path):
    """``mcdenoise train``'s scanner (mcdenoise/train/patches.py) on the OIDN set: the same
    (image, spp) pairs as on the render folder, the same colour and reference pixels."""
    from mcdenoise.train.patches import load_items, scan_dataset

    src = render_folder(tmp_path / "render", ids=("alpha", "beta"), spp=(1, 4))
    write_oidn_layout(src, tmp_path / "oidn")
    ours, theirs = scan_dataset(src), scan_dataset(tmp_path / "oidn")
    assert [(e.image, e.spp) for e in theirs] == [(e.image, e.spp) for e in ours]

    def prepare(buffers, ref):
        return {"color": buffers["color"], "albedo": buffers["albedo"], "reference": ref}

    a, _ = load_items(ours, prepare)
    b, _ = load_items(theirs, prepare)
    assert len(a) == len(b) == 4
    for x, y in zip(a, b, strict=True):
        for key in ("color", "albedo", "reference"):
            assert torch.equal(x.tensors[key], y.tensors[key]), key

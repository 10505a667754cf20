"""The ``cycles`` profile: Blender multilayer EXR (mcdenoise/io/profiles/cycles.py)."""

from __future__ import annotations

import importlib.util
import logging
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cycles_checks import check_conventions, load_facts
from profile_files import BLENDER_ATTRS, blender_file, blender_layer, planes, stack, write

from mcdenoise.errors import ExrError
from mcdenoise.io import ProfileError, describe, load_buffers
from mcdenoise.io.exr import probe_exr


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


# --- Blender 5's layout: one part per pass, header attributes in part 0 only ----------------
def _blender(tmp_path, rng, **kw):
    layers = {
        "ViewLayer": blender_layer(rng, denoising=True),
        "Layer2": blender_layer(rng, denoising=False, position=False),
    }
    return blender_file(tmp_path / "b.exr", layers, BLENDER_ATTRS), layers


def test_blender_parts_attributes_in_part_zero_only(tmp_path, rng):
    path, layers = _blender(tmp_path, rng)
    parts = probe_exr(path)
    assert [p.name for p in parts][:2] == ["ViewLayer.Combined", "ViewLayer.Depth"]
    assert "BlenderMultiChannel" in parts[0].attributes
    assert all("cycles.ViewLayer.samples" not in p.attributes for p in parts[1:])
    fb = load_buffers(path)
    assert fb.profile == "cycles:ViewLayer" and fb.spp == 16
    # With a part: the part's whole layer, and detection and spp from part 0.
    for part in ("ViewLayer.Vector", "ViewLayer", 3, "ViewLayer.Combined"):
        via = load_buffers(path, part=part)
        assert via.profile == "cycles:ViewLayer" and via.spp == 16, part
        assert via.names() == fb.names(), part
        np.testing.assert_array_equal(via["motion"].numpy(), fb["motion"].numpy())
    for part in ("Layer2", "Layer2.Normal", len(probe_exr(path)) - 1):
        via = load_buffers(path, part=part)
        assert via.profile == "cycles:Layer2" and via.spp == 16, part
        np.testing.assert_array_equal(
            via["color"].numpy(), np.stack([layers["Layer2"]["Combined"][c] for c in "RGB"])
        )
    with pytest.raises(ExrError, match="no part"):
        load_buffers(path, part="Layer3")


def test_blender_second_layer_by_profile_reads_its_own_samples(tmp_path, rng):
    layers = {
        "ViewLayer": blender_layer(rng, denoising=True),
        "Layer2": blender_layer(rng, denoising=False, position=False),
    }
    attrs = {**BLENDER_ATTRS, "cycles.Layer2.samples": "64"}
    path = blender_file(tmp_path / "b.exr", layers, attrs)
    assert load_buffers(path).spp == 16
    fb = load_buffers(path, profile="cycles:Layer2")
    assert fb.profile == "cycles:Layer2" and fb.spp == 64
    assert load_buffers(path, part="Layer2").spp == 64


def test_blender_motion_from_vector_signs(tmp_path, rng):
    """Vector.XY = previous - current, y up; Vector.ZW = current - next, y up (Cycles'
    primitive_motion_vector); the canonical buffers are x right, y down, p + motion."""
    path, layers = _blender(tmp_path, rng)
    fb = load_buffers(path)
    v = layers["ViewLayer"]["Vector"]
    np.testing.assert_array_equal(fb["motion"].numpy(), np.stack([v["X"], -v["Y"]]))
    np.testing.assert_array_equal(fb["motion_next"].numpy(), np.stack([-v["Z"], v["W"]]))
    assert fb.channels["motion"] == ["ViewLayer.Vector.X", "ViewLayer.Vector.Y"]
    assert "motion_valid" not in fb  # Cycles writes no validity mask


def test_blender_normal_and_depth_prefer_canonical_passes(tmp_path, rng, caplog):
    path, layers = _blender(tmp_path, rng)
    with caplog.at_level(logging.WARNING, logger="mcdenoise"):
        fb = load_buffers(path)
    L = layers["ViewLayer"]
    # World-space Normal, not the camera-space Denoising Normal; ray-distance Denoising Depth.
    np.testing.assert_array_equal(fb["normal"].numpy(), np.stack([L["Normal"][c] for c in "XYZ"]))
    np.testing.assert_array_equal(fb["depth"].numpy()[0], L["Denoising Depth"]["Z"])
    np.testing.assert_array_equal(
        fb["position"].numpy(), np.stack([L["Position"][c] for c in "XYZ"])
    )
    assert not [
        r for r in caplog.records if "normal" in r.getMessage() or "depth" in r.getMessage()
    ]


def test_blender_layer_without_denoising_data_is_not_silent(tmp_path, rng, caplog):
    path, layers = _blender(tmp_path, rng)
    with caplog.at_level(logging.WARNING, logger="mcdenoise"):
        fb = load_buffers(path, profile="cycles:Layer2")
    L = layers["Layer2"]
    assert fb.names() == ["color", "normal", "depth", "motion", "motion_next"]
    z = L["Depth"]["Z"]
    want = np.where(z >= 1e10, 0, z)
    np.testing.assert_array_equal(fb["depth"].numpy()[0], want)
    assert fb["depth"].numpy()[0, 0, :3].tolist() == [0, 0, 0]
    msgs = [r.getMessage() for r in caplog.records]
    assert len(msgs) == 1 and "depth: planar depth" in msgs[0] and str(path) in msgs[0]
    assert any("planar depth" in n for n in fb.attributes["_notes"])
    info = describe(path, profile="cycles:Layer2")
    assert any("planar depth" in n for n in info.notes)
    assert any("1e+10 (no hit) -> 0" in b.conversion for b in info.buffers if b.name == "depth")


def test_blender_camera_space_normal_only_is_reported(tmp_path, rng, caplog):
    layer = blender_layer(rng, denoising=True)
    del layer["Normal"]
    path = blender_file(tmp_path / "c.exr", {"ViewLayer": layer}, BLENDER_ATTRS)
    with caplog.at_level(logging.WARNING, logger="mcdenoise"):
        fb = load_buffers(path)
    np.testing.assert_array_equal(
        fb["normal"].numpy(), np.stack([layer["Denoising Normal"][c] for c in "XYZ"])
    )
    msgs = [r.getMessage() for r in caplog.records]
    assert len(msgs) == 1 and "camera-space normals" in msgs[0]


def test_blender_albedo_above_one_is_reported_once_and_kept(tmp_path, rng, caplog):
    layer = blender_layer(rng, denoising=True)
    layer["Denoising Albedo"]["G"][2, 4] = 50.7
    layer["Denoising Albedo"]["R"][3, 1] = 1.5
    layer["Denoising Albedo"]["B"][3, 1] = 2.0  # same pixel: counted once
    path = blender_file(tmp_path / "a.exr", {"ViewLayer": layer}, BLENDER_ATTRS)
    with caplog.at_level(logging.WARNING, logger="mcdenoise"):
        fb = load_buffers(path)
    assert float(fb["albedo"].max()) == pytest.approx(50.7, rel=1e-6)
    msgs = [r.getMessage() for r in caplog.records]
    assert len(msgs) == 1
    assert "albedo: 2 pixel(s) above 1 (max 50.7)" in msgs[0] and "emission" in msgs[0]
    # describe() reports it as a note, without logging it a second time.
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="mcdenoise"):
        info = describe(path)
    assert any("above 1" in n for n in info.notes) and not caplog.records


def test_albedo_in_range_gives_no_warning(tmp_path, rng, caplog):
    path = blender_file(
        tmp_path / "a.exr", {"ViewLayer": blender_layer(rng, denoising=True)}, BLENDER_ATTRS
    )
    with caplog.at_level(logging.WARNING, logger="mcdenoise"):
        fb = load_buffers(path)
    assert "albedo" in fb and not caplog.records and "_notes" not in fb.attributes


def test_part_zero_attributes_are_not_inherited_outside_blender_files(tmp_path, write_multipart):
    """Only Blender writes file-wide attributes in part 0: another file's part keeps its own."""
    ones = np.ones((4, 4), np.float32)
    path = write_multipart(
        tmp_path / "m.exr",
        [
            {"name": "a", "channels": {c: ones for c in "RGB"}, "attributes": {"mcdenoise:spp": 8}},
            {"name": "b", "channels": {c: 2 * ones for c in "RGB"}},
        ],
    )
    assert load_buffers(path, part="b").spp is None


# --- a real Blender 5.0.1 file (data/recipes/cycles/render_cycles.py, 32x32, half, ZIP) ----
REAL = Path(__file__).resolve().parents[1] / "data" / "cycles_32"


def test_real_cycles_file_conventions(caplog):
    check_conventions(REAL / "cycles_spp4.exr", load_facts(REAL / "scene.json"), caplog)


def _bpy_python() -> str | None:
    """A Python that can import bpy: this one, or $MCDENOISE_BPY_PYTHON."""
    if importlib.util.find_spec("bpy") is not None:
        return sys.executable
    exe = os.environ.get("MCDENOISE_BPY_PYTHON")
    return exe if exe and shutil.which(exe) else None


@pytest.mark.slow
def test_fresh_cycles_render_conventions(tmp_path, caplog):
    """Render with Blender (bpy) now and check every convention again (Blender updates)."""
    exe = _bpy_python()
    if exe is None:
        pytest.skip("needs bpy: install the bpy wheel in a venv, set MCDENOISE_BPY_PYTHON")
    script = (
        Path(__file__).resolve().parents[3] / "data" / "recipes" / "cycles" / "render_cycles.py"
    )
    run = subprocess.run(
        [exe, str(script), str(tmp_path), "--res", "32", "--spp", "4", "--ref-spp", "8"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    check_conventions(tmp_path / "cycles_spp4.exr", load_facts(tmp_path / "scene.json"), caplog)

    # With Blender's own denoiser on, Combined is denoised and every layer also gets the noisy
    # image as "Noisy Image": that is what must be read, in both layers.
    den = tmp_path / "denoised"
    run = subprocess.run(
        [exe, str(script), str(den), "--res", "16", "--spp", "4", "--ref-spp", "4",
         "--blender-denoiser"],
        capture_output=True,
        text=True,
        timeout=600,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-2000:]
    for layer in ("ViewLayer", "Layer2"):
        fb = load_buffers(den / "cycles_spp4.exr", profile=f"cycles:{layer}")
        assert fb.channels["color"] == [f"{layer}.Noisy Image.{c}" for c in "RGB"]
        combined = load_buffers(den / "cycles_spp4.exr", profile=f"cycles:{layer}", mapping={
            "color": [f"{layer}.Combined.{c}" for c in "RGB"]})["color"]  # fmt: skip
        assert not np.allclose(combined.numpy(), fb["color"].numpy())

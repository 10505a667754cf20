"""Tests of ``mcdenoise/experiments/viewer.py``: the data of the report's interactive viewer.

The synthetic experiment of ``synthetic_viewer.py`` (two scenes of 36×40, 1 and 4 spp; the
renderer left a 2×2 block of NaN in one noisy input) with methods that agree (``box``,
``soft``), one that disagrees in a planted 12×12 square (``odd``) and one that cannot run
(``refuse``). The stored pixels, decoded in Python the way the browser does (base64 → zlib →
byte planes → float16), must be the EXR outputs within float16 precision; the automatic crop
must find the planted square; missing outputs, an unreadable reference and a size budget give
notes, never a traceback. A sequence experiment stores every frame.
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest
from synthetic_viewer import (
    PLANT,
    SIZE,
    decode_f16,
    decode_u8,
    load_scene,
    run_sequence_experiment,
    run_viewer_experiment,
)

from mcdenoise.experiments import viewer as viewer_module
from mcdenoise.experiments.dataset import read_level, read_reference
from mcdenoise.experiments.viewer import crop_size, disagreement_crops, viewer_section
from mcdenoise.io import load_buffers


@pytest.fixture(scope="module")
def experiment(tmp_path_factory):
    return run_viewer_experiment(tmp_path_factory.mktemp("viewer"))


def test_the_viewer_files_are_written_and_the_page_loads_them(experiment):
    out, _ = experiment
    page = (out / "report.html").read_text(encoding="utf-8")
    for name in ("viewer.js", "viewer.css", "scene_00.js", "scene_01.js"):
        assert (out / "viewer" / name).is_file(), name
    assert page.count('class="mcdv"') == 2 and 'id="viewer-0"' in page and 'id="viewer-1"' in page
    assert "How to use the viewer:" in page
    # offline: the one script is viewer/viewer.js, by a relative path, none inline; it loads
    # each scene's data file, named by the viewer's data-src
    scripts = re.findall(r"<script\b([^>]*)>", page)
    assert scripts and all(s == ' defer src="viewer/viewer.js"' for s in scripts)
    assert re.findall(r'data-src="([^"]+)"', page) == ["viewer/scene_00.js", "viewer/scene_01.js"]
    assert "http://" not in page and "https://" not in page
    # the viewer follows the static strip, which stays as the no-script fallback
    assert page.index("Images at 4 spp") < page.index('id="viewer-0"')
    js = (out / "viewer" / "viewer.js").read_text(encoding="utf-8")
    assert "DecompressionStream" in js and "viewer-selftest" in js and "http" not in js


def test_stored_pixels_are_the_exr_outputs_within_float16_precision(experiment):
    out, result = experiment
    for index, scene in enumerate(result.scenes):
        data = load_scene(out / "viewer" / f"scene_{index:02d}.js")
        h, w = data["height"], data["width"]
        assert (h, w) == SIZE and data["frames"] == 1 and data["levels"] == [1, 4]
        assert data["labels"] == [*result.labels, "reference"]
        by = {(i["label"], i["spp"]): i for i in data["images"]}
        # every method and the noisy input at every level, and the reference
        assert set(by) == {(lb, s) for lb in result.labels for s in (1, 4)} | {
            ("reference", scene.reference_spp)
        }
        checked = 0
        for (label, spp), entry in by.items():
            if label == "refuse":
                assert "could not run" in entry["missing"] and "frames" not in entry
                continue
            if label == "reference":
                exr = read_reference(scene.reference_file)["color"].numpy()
            elif label == "noisy":
                level = next(lv for lv in scene.levels if lv.spp == spp)
                exr = read_level(scene.noisy_file, level)["color"].numpy()
            else:
                exr = load_buffers(out / result.record(scene.id, spp, label)["output"])
                exr = exr["color"].numpy()
            got = decode_f16(entry["frames"][0], (3, h, w))
            np.testing.assert_array_equal(got, exr.astype(np.float16).astype(np.float32))
            np.testing.assert_allclose(got, exr, rtol=2**-11, atol=2**-24, equal_nan=True)
            checked += 1
        assert checked == 2 * 4 + 1  # noisy, box, soft, odd at two levels; the reference
        if scene.id == "alpha":  # the renderer's NaN pixels are kept
            noisy = decode_f16(by[("noisy", 4)]["frames"][0], (3, h, w))
            assert np.isnan(noisy[:, :2, :2]).all() and np.isfinite(noisy[:, 2:, 2:]).all()


def test_flip_maps_are_stored_at_the_strip_level_where_flip_evaluator_is_installed(experiment):
    out, _ = experiment
    alpha, beta = (load_scene(out / "viewer" / f"scene_{i:02d}.js") for i in (0, 1))
    by = {(i["label"], i["spp"]): i for i in beta["images"]}
    data = beta
    try:
        import flip_evaluator  # noqa: F401  # optional
    except ImportError:
        assert "flip_evaluator is not installed" in data["flip_note"]
        assert not any("flip" in i for i in data["images"])
        return
    assert data["flip_note"] is None and data["flip_spp"] == 4
    box = decode_u8(by[("box", 4)]["flip"][0], (data["height"], data["width"]))
    noisy = decode_u8(by[("noisy", 4)]["flip"][0], (data["height"], data["width"]))
    assert 0 < box.mean() < noisy.mean()  # the denoised image is closer to the reference
    assert {(i["label"], i["spp"]) for i in data["images"] if "flip" in i} == {
        (label, 4) for label in ("noisy", "box", "soft", "odd")
    }
    nan = next(i for i in alpha["images"] if (i["label"], i["spp"]) == ("noisy", 4))
    assert nan["flip_missing"] == "FLIP needs finite pixels" and "flip" not in nan


def test_the_crops_are_where_the_methods_disagree(experiment):
    out, result = experiment
    x, y, s = PLANT
    for index in range(len(result.scenes)):
        data = load_scene(out / "viewer" / f"scene_{index:02d}.js")
        assert data["crop_spp"] == 4 and len(data["crops"]) == 2
        first, second = data["crops"]
        assert first["w"] == first["h"] == crop_size(*SIZE) == 12
        assert (first["x"], first["y"]) == (x, y)
        # the second does not overlap the first
        assert abs(second["x"] - x) >= s or abs(second["y"] - y) >= s
        assert first["score"] > 10 * second["score"]


def test_disagreement_crops_on_arrays():
    rng = np.random.default_rng(0)
    ref = np.full((3, 64, 80), 0.5)
    a = ref + rng.normal(0, 0.01, ref.shape)
    b = ref + rng.normal(0, 0.01, ref.shape)
    b[:, 40:50, 5:15] += 2.0  # a disagreement of 10×10
    b[:, 3, 70] = np.inf  # a single non-finite pixel does not outweigh it
    crops = disagreement_crops([a, b], ref)
    assert crops[0]["w"] == 21  # a third of 64
    cx, cy = crops[0]["x"] + 10, crops[0]["y"] + 10
    assert 5 <= cx < 15 and 40 <= cy < 50
    assert disagreement_crops([ref, ref], ref) == []  # nothing disagrees: no crop
    assert disagreement_crops([], ref) == []
    one = disagreement_crops([b], ref, count=1)  # one method: where its error is largest
    assert 40 - 21 < one[0]["y"] <= 49 and 5 - 21 < one[0]["x"] <= 14


def test_missing_outputs_are_not_available_with_the_reason(experiment, tmp_path):
    _, result = experiment
    scene = result.scenes[0]
    # written elsewhere: the outputs (relative to the report's folder) are not there
    html = viewer_section(result, scene, 0, tmp_path)
    assert 'id="viewer-0"' in html
    data = load_scene(tmp_path / "viewer" / "scene_00.js")
    by = {(i["label"], i["spp"]): i for i in data["images"]}
    assert by[("box", 4)]["missing"].startswith("output file missing: outputs/")
    assert "could not run" in by[("refuse", 1)]["missing"]
    assert "frames" in by[("noisy", 1)] and "frames" in by[("reference", scene.reference_spp)]
    assert data["crops"] == []  # no method output: nothing to compare


def test_an_unreadable_reference_is_a_note_and_prunes_stale_files(experiment, tmp_path):
    _, result = experiment
    gone = dataclasses.replace(result.scenes[1], reference_file=str(tmp_path / "gone.exr"))
    (tmp_path / "viewer").mkdir()
    for name in ("scene_01.js", "scene_07.js"):  # an earlier report's
        (tmp_path / "viewer" / name).write_text("old", encoding="ascii")
    html = viewer_section(result, gone, 1, tmp_path)
    assert html.startswith('<p class="notes">Interactive viewer not available: the reference')
    assert not (tmp_path / "viewer" / "scene_01.js").exists()
    assert not (tmp_path / "viewer" / "scene_07.js").exists()  # past the two scenes
    assert (tmp_path / "viewer" / "viewer.js").is_file()


def test_levels_past_the_size_budget_are_named_not_stored(experiment, tmp_path, monkeypatch):
    out, result = experiment
    monkeypatch.setattr(viewer_module, "MAX_SCENE_BYTES", 1)
    viewer_section(result, result.scenes[0], 0, out.parent / "budget")
    data = load_scene(out.parent / "budget" / "viewer" / "scene_00.js")
    assert data["levels"] == [4]  # the strip level only
    assert {i["spp"] for i in data["images"] if i["label"] != "reference"} == {4}
    assert data["notes"] == ["not stored, to keep the scene under 1e-06 MB of pixels: 1 spp"]


def test_values_beyond_float16_are_clipped_and_counted():
    text, clipped = viewer_module.encode_f16(
        np.array([[[1e6, -1e6, np.inf, np.nan, 0.5]]], dtype=np.float32)
    )
    got = decode_f16(text, (1, 1, 5))[0, 0]
    assert clipped == 2
    assert got[0] == 65504 and got[1] == -65504 and np.isposinf(got[2]) and np.isnan(got[3])
    assert got[4] == 0.5


def test_a_sequence_stores_every_frame(tmp_path, fake_methods):
    result = run_sequence_experiment(tmp_path, fake_methods)
    page = (tmp_path / "out" / "report.html").read_text(encoding="utf-8")
    assert page.index("Over time at 2 spp") < page.index('id="viewer-0"')
    data = load_scene(tmp_path / "out" / "viewer" / "scene_00.js")
    assert data["frames"] == 3 and data["sequence"] is True
    scene = result.scenes[0]
    by = {(i["label"], i["spp"]): i for i in data["images"]}
    assert all(len(i["frames"]) == 3 for i in data["images"])
    rec = result.record(scene.id, 8, "box")
    for t in range(3):
        exr = load_buffers(tmp_path / "out" / rec["output"] / f"frame_{t:04d}.exr")
        got = decode_f16(by[("box", 8)]["frames"][t], (3, 16, 16))
        np.testing.assert_array_equal(got, exr["color"].numpy().astype(np.float16))
        ref = load_buffers(scene.frames[t][1])["color"].numpy()
        got = decode_f16(by[("reference", scene.reference_spp)]["frames"][t], (3, 16, 16))
        np.testing.assert_array_equal(got, ref.astype(np.float16))

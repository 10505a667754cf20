"""Tests of ``mcdenoise/experiments/dataset.py``: reading a render folder for an experiment."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from synthetic_data import JIT_SECONDS, make_render_folder

from mcdenoise.experiments.dataset import load_dataset, render_folder
from mcdenoise.experiments.spec import parse_experiment
from mcdenoise.experiments.spec_fields import ExperimentError


def test_levels_exclude_jit_and_keep_the_manifest_order(tmp_path: Path):
    folder = make_render_folder(tmp_path / "d", spp=(1, 4, 16), seconds_per_spp=0.5)
    scenes = load_dataset(folder)
    assert [s.id for s in scenes] == ["alpha", "beta"]
    a = scenes[0]
    assert [lv.spp for lv in a.levels] == [1, 4, 16] and a.level(4).part == "spp4"
    assert [lv.render_seconds for lv in a.levels] == pytest.approx([0.5, 2.0, 8.0])
    assert all(lv.jit_seconds == pytest.approx(JIT_SECONDS) for lv in a.levels)
    assert a.noisy == (folder / "alpha.exr").resolve() and a.reference.parent.name == "ref"
    assert a.reference_spp == 4096 and a.seed == 1000
    assert a.fingerprint != scenes[1].fingerprint
    sub = load_dataset(folder, ["beta"], [4, 16])
    assert [s.id for s in sub] == ["beta"] and [lv.spp for lv in sub[0].levels] == [4, 16]


def test_fingerprint_follows_the_spec_and_seed(tmp_path: Path):
    folder = make_render_folder(tmp_path / "d")
    before = load_dataset(folder)[0].fingerprint
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["images"][0]["seed"] = 7
    (folder / "manifest.json").write_text(json.dumps(manifest))
    assert load_dataset(folder)[0].fingerprint != before


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        ("no-manifest", "no manifest.json and no reference"),
        ("missing-file", "file .* is missing"),
        ("frames", "holds sequences"),
        ("level", "has no level"),
        ("id", "is not in the manifest"),
    ],
)
def test_unusable_folders_are_refused_with_one_line(tmp_path: Path, damage: str, message: str):
    folder = make_render_folder(tmp_path / "d")
    ids, spp = None, None
    if damage == "no-manifest":  # and no references: not a folder of inputs either
        (folder / "manifest.json").unlink()
        for ref in (folder / "ref").iterdir():
            ref.unlink()
    elif damage == "missing-file":
        (folder / "ref" / "beta.exr").unlink()
    elif damage == "frames":
        m = json.loads((folder / "manifest.json").read_text())
        m["settings"]["frames"] = 4
        (folder / "manifest.json").write_text(json.dumps(m))
    elif damage == "level":
        spp = [1, 8]
    else:
        ids = ["gamma"]
    with pytest.raises(ExperimentError, match=message) as info:
        load_dataset(folder, ids, spp)
    assert "\n" not in str(info.value)


def test_a_render_folder_without_its_manifest_is_a_folder_of_inputs(tmp_path: Path):
    """Levels from the parts spp<n>, references from ref/, the render seconds unknown."""
    folder = make_render_folder(tmp_path / "d")
    with_manifest = load_dataset(folder)
    (folder / "manifest.json").unlink()
    scenes = load_dataset(folder)
    assert [s.id for s in scenes] == [s.id for s in with_manifest]
    for s, m in zip(scenes, with_manifest, strict=True):
        assert [(lv.spp, lv.part) for lv in s.levels] == [(lv.spp, lv.part) for lv in m.levels]
        assert all(lv.render_seconds is None for lv in s.levels)
        assert s.reference == m.reference


def test_render_folder_is_relative_to_the_output(tmp_path: Path):
    scenes = Path(__file__).resolve().parents[2] / "data" / "scenes"
    spec = parse_experiment({"scenes": {"specs": [str(scenes / "cornell.toml")]}})
    assert render_folder(spec, tmp_path) == tmp_path / "data"
    spec = parse_experiment(
        {"scenes": {"specs": [str(scenes / "cornell.toml")]}, "render": {"folder": "/abs/x"}}
    )
    assert render_folder(spec, tmp_path) == Path("/abs/x")

"""``mcdenoise eval --ref REF OUT``: an output whose recorded source records another scene than
the reference does (the ``mcdenoise:scene``/``image``/``frame`` headers) is refused, naming both
(``--force``: a warning). Only recorded provenance can contradict the pairing the user gave:
outputs with no recorded source, and files without scene headers (a user's own ``noisy.exr``
and ``ref.exr``), are evaluated without a word; file names are not taken for scenes."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from fast_methods import run_cli as run

from mcdenoise.eval.matching import same_scene
from mcdenoise.io import FeatureBuffers, load_buffers, save_buffers

SAMPLES = Path(__file__).resolve().parents[2] / "data" / "samples"
REF = SAMPLES / "ref"


def denoise(src: Path, out: str) -> Path:
    r = run("denoise", src, "-m", "box3", "-o", out)
    assert r.exit_code == 0, r.output
    return Path(out)


def without_scene(src: Path, dst: Path) -> Path:
    """``src``'s colour with no ``mcdenoise:*`` attributes (as another renderer writes it)."""
    color = load_buffers(src)["color"]
    save_buffers(dst, FeatureBuffers({"color": color}, spp=4))
    return dst


def test_denoise_records_the_scene_of_its_input(here: Path) -> None:
    out = denoise(SAMPLES / "cornell_spp4.exr", "o.exr")
    attrs = load_buffers(out).attributes
    assert attrs["mcdenoise:scene"] == "cornell"
    assert attrs["mcdenoise:source"] == str((SAMPLES / "cornell_spp4.exr").resolve())


def test_another_scene_is_refused_naming_both(here: Path) -> None:
    denoise(SAMPLES / "cornell_spp4.exr", "out.exr")
    r = run("eval", "--ref", REF / "caustic.exr", "out.exr", "-o", "rep")
    assert r.exit_code == 1 and r.stdout == ""
    (err,) = r.stderr.splitlines()
    assert "cornell_spp4.exr" in err and "scene 'cornell'" in err
    assert "caustic.exr" in err and "scene 'caustic'" in err and "--force" in err
    assert not (here / "rep").exists()  # nothing written


def test_force_evaluates_with_a_warning_that_the_report_keeps(here: Path) -> None:
    denoise(SAMPLES / "cornell_spp4.exr", "out.exr")
    r = run("eval", "--ref", REF / "caustic.exr", "out.exr", "-o", "rep", "--force")
    assert r.exit_code == 0, r.output
    (warning,) = r.stderr.splitlines()
    assert warning.startswith("mcdenoise: warning: output out.exr was made from ")
    assert "'cornell'" in warning and "'caustic'" in warning
    assert "caustic" in r.stdout  # the table: results on stdout
    records = json.loads((here / "rep" / "results.json").read_text())["records"]
    out = next(rec for rec in records if rec["file"] == "out.exr")
    assert any("'caustic'" in note for note in out["notes"])


def test_the_right_scene_passes_silently(here: Path) -> None:
    denoise(SAMPLES / "cornell_spp4.exr", "out.exr")
    r = run("eval", "--ref", REF / "cornell.exr", "out.exr", "-o", "rep")
    assert r.exit_code == 0, r.output
    assert r.stderr == ""


def test_a_folder_of_references_checks_the_matched_one(here: Path) -> None:
    """An output renamed after another scene is matched to that reference by name, and the
    recorded source gives it away."""
    denoise(SAMPLES / "cornell_spp4.exr", "caustic_spp4_box3.exr")
    r = run("eval", "--ref", REF, "caustic_spp4_box3.exr", "-o", "rep")
    assert r.exit_code == 1
    assert "scene 'cornell'" in r.stderr and "scene 'caustic'" in r.stderr


def test_no_recorded_source_is_accepted_without_a_word(here: Path) -> None:
    shutil.copy(SAMPLES / "cornell_spp4.exr", here / "mine.exr")  # not made by denoise
    r = run("eval", "--ref", REF / "caustic.exr", "mine.exr", "-o", "rep")
    assert r.exit_code == 0, r.output
    assert r.stderr == ""


def test_without_scene_headers_any_names_are_accepted(here: Path) -> None:
    """A user's own files: ``noisy.exr`` denoised into ``out.exr``, judged against ``ref.exr``;
    nothing recorded says which scene either shows, so no --force is needed."""
    without_scene(SAMPLES / "cornell_spp4.exr", here / "noisy.exr")
    without_scene(REF / "cornell.exr", here / "ref.exr")
    denoise(here / "noisy.exr", "out.exr")
    assert "mcdenoise:scene" not in load_buffers(here / "out.exr").attributes
    r = run("eval", "--ref", "ref.exr", "out.exr", "-o", "rep")
    assert r.exit_code == 0, r.output
    assert r.stderr == ""
    records = json.loads((here / "rep" / "results.json").read_text())["records"]
    assert sorted(Path(rec["file"]).name for rec in records) == ["noisy.exr", "out.exr"]


def test_one_side_without_a_scene_header_is_accepted(here: Path) -> None:
    """A header on one side only contradicts nothing: a headerless render of another name
    against a sample reference, and a sample's output against a headerless reference."""
    without_scene(SAMPLES / "dof_spp4.exr", here / "dof_spp4.exr")
    denoise(here / "dof_spp4.exr", "a.exr")
    r = run("eval", "--ref", REF / "cornell.exr", "a.exr", "-o", "rep")
    assert r.exit_code == 0 and r.stderr == "", r.output
    denoise(SAMPLES / "cornell_spp4.exr", "b.exr")
    without_scene(REF / "caustic.exr", here / "mine.exr")
    r = run("eval", "--ref", "mine.exr", "b.exr", "-o", "rep2")
    assert r.exit_code == 0 and r.stderr == "", r.output


def test_a_moved_source_is_judged_by_what_the_output_records(here: Path) -> None:
    """``mcdenoise denoise`` copies the scene into its output: the source may be gone."""
    src = here / "cornell_spp4.exr"
    shutil.copy(SAMPLES / "cornell_spp4.exr", src)
    denoise(src, "a.exr")
    src.unlink()
    r = run("eval", "--ref", REF / "caustic.exr", "a.exr", "-o", "rep")
    assert r.exit_code == 1 and "scene 'cornell'" in r.stderr and "scene 'caustic'" in r.stderr


def test_a_chain_of_outputs_is_followed_to_the_scene(here: Path) -> None:
    first = denoise(SAMPLES / "cornell_spp4.exr", "first.exr")
    second = denoise(first, "second.exr")
    assert load_buffers(second).attributes["mcdenoise:scene"] == "cornell"
    r = run("eval", "--ref", REF / "caustic.exr", "second.exr", "-o", "rep")
    assert r.exit_code == 1 and "'cornell'" in r.stderr


def test_the_rule() -> None:
    scene, image, frame = "mcdenoise:scene", "mcdenoise:image", "mcdenoise:frame"
    assert same_scene({scene: "a"}, {scene: "a"})
    assert not same_scene({scene: "a"}, {scene: "b"})
    assert not same_scene({scene: "a", image: "a_2"}, {scene: "a", image: "a"})
    assert not same_scene({scene: "a", frame: "3"}, {scene: "a", frame: "4"})
    assert same_scene({scene: "a", image: "a_2"}, {scene: "a"})  # recorded on one side only
    assert same_scene({scene: "cornell"}, {})  # one header: nothing contradicts
    assert same_scene({}, {})  # names are not scenes (noisy.exr and ref.exr)

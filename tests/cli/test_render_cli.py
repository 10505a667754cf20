"""``mcdenoise render`` as users meet it: a tiny data set end to end, and one-line errors.

Renders are 16×16 pixels at a few spp in ``scalar_rgb``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner
from mcdenoise_cli.main import main
from scene_specs import BALL_SCENE

from mcdenoise.io import load_buffers

TINY = ("--res", "16", "--spp", "1,4", "--ref-spp", "8", "--variant", "scalar_rgb")


def run(*args: str):
    return CliRunner().invoke(main, list(args), catch_exceptions=False)


def one_line_error(result) -> str:
    assert result.exit_code not in (0, None), result.output
    err = result.stderr.strip()
    assert "Traceback" not in result.output + err
    assert len(err.splitlines()) == 1, err
    return err


def spec(folder: Path, name: str = "ball", text: str = BALL_SCENE) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.toml"
    path.write_text(text.format(name=name), encoding="utf-8")
    return path


@pytest.mark.mitsuba
def test_render_a_folder_of_specs_then_info_and_denoise_a_level(tmp_path: Path) -> None:
    specs = tmp_path / "scenes"
    spec(specs, "a"), spec(specs, "b")
    out = tmp_path / "data"
    r = run("render", str(specs), "-o", str(out), *TINY)
    assert r.exit_code == 0, r.output + r.stderr
    assert "rendered 2, skipped 0" in r.output and "scalar_rgb" in r.output
    assert sorted(p.name for p in out.glob("*.exr")) == ["a.exr", "b.exr"]
    assert sorted(p.name for p in (out / "ref").glob("*.exr")) == ["a.exr", "b.exr"]
    manifest = json.loads((out / "manifest.json").read_text())
    assert [i["id"] for i in manifest["images"]] == ["a", "b"]
    assert manifest["settings"]["spp"] == [1, 4] and manifest["settings"]["ref_spp"] == 8

    again = run("render", str(specs), "-o", str(out), *TINY)
    assert again.exit_code == 0 and "rendered 0, skipped 2" in again.output

    info = run("info", str(out / "a.exr"), "--part", "spp4", "--json")
    assert info.exit_code == 0, info.output
    record = json.loads(info.output)
    assert record["spp"] == 4 and "color_var" in json.dumps(record)

    den = tmp_path / "den.exr"
    d = run(
        "denoise", str(out / "a.exr"), "--part", "spp4", "-o", str(den), "-m", "cross-bilateral"
    )
    assert d.exit_code == 0, d.output + d.stderr
    assert load_buffers(den).spp == 4


@pytest.mark.mitsuba
def test_two_shard_jobs_share_one_folder(tmp_path: Path) -> None:
    files = [str(spec(tmp_path / "s", f"x{i}")) for i in range(3)]
    out = tmp_path / "out"
    for shard in ("1/2", "2/2"):
        r = run("render", *files, "-o", str(out), "--shard", shard, *TINY)
        assert r.exit_code == 0 and f"(shard {shard})" in r.output, r.output + r.stderr
    manifest = json.loads((out / "manifest.json").read_text())
    assert [i["id"] for i in manifest["images"]] == ["x0", "x1", "x2"]
    assert len(manifest["shards"]) == 2


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("--shard", "3/2"), "shard 3/2"),
        (("--shard", "two"), "--shard 'two'"),
        (("--spp", "0"), "--spp '0'"),
        (("--spp", "16,4"), "strictly increasing"),
        (("--ref-spp", "0"), "ref_spp"),
        (("--variant", "gpu"), "unknown Mitsuba variant 'gpu'"),
        (("--res", "0"), "--res '0'"),
        (("--seed", "-1"), "seed"),
    ],
)
def test_bad_options_give_one_line(tmp_path: Path, args, needle) -> None:
    msg = one_line_error(run("render", str(spec(tmp_path)), "-o", str(tmp_path / "o"), *args))
    assert needle in msg
    assert not (tmp_path / "o").exists()


def test_bad_spec_names_file_and_key(tmp_path: Path) -> None:
    bad = spec(tmp_path, "bad", BALL_SCENE.replace('"direct"', '"direct", "sparkles"'))
    msg = one_line_error(run("render", str(bad), "-o", str(tmp_path / "o")))
    assert "bad.toml" in msg and "effects" in msg and "sparkles" in msg


def test_nothing_to_render_and_unwritable_output(tmp_path: Path) -> None:
    assert "nothing to render" in one_line_error(run("render", "-o", str(tmp_path / "o")))
    if Path("/proc/self").is_dir():  # Linux: nobody, root included, can create files there
        msg = one_line_error(run("render", str(spec(tmp_path)), "-o", "/proc/self/out", *TINY))
        assert "/proc/self/out" in msg
    empty = tmp_path / "empty"
    empty.mkdir()
    assert "no *.toml" in one_line_error(run("render", str(empty), "-o", str(tmp_path / "o")))


def test_missing_mitsuba_says_how_to_install(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "mitsuba", None)
    msg = one_line_error(run("render", str(spec(tmp_path)), "-o", str(tmp_path / "o"), *TINY))
    assert "pip install 'mcdenoise[render]'" in msg


def test_random_without_the_generator_is_a_clear_error(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "mcdenoise.render.random_scenes", None)
    msg = one_line_error(run("render", "--random", "2", "-o", str(tmp_path / "o"), *TINY))
    assert "--random" in msg and "random_scenes" in msg


@pytest.mark.mitsuba
def test_random_scenes_are_rendered_and_recorded(tmp_path: Path) -> None:
    pytest.importorskip("mcdenoise.render.random_scenes")
    from mcdenoise.render.random_scenes import random_spec
    from mcdenoise.render.scene_spec import parse_spec

    out = tmp_path / "r"
    r = run("render", "--random", "2", "--seed", "5", "-o", str(out), *TINY)
    assert r.exit_code == 0, r.output + r.stderr
    images = json.loads((out / "manifest.json").read_text())["images"]
    assert [i["id"] for i in images] == ["random_s5_00000", "random_s5_00001"]
    for k, rec in enumerate(images):
        want = random_spec(5, k).to_dict()
        want.pop("source", None)
        assert parse_spec(rec["spec"]) == parse_spec(want)
        assert load_buffers(out / rec["files"]["noisy"], part="spp4").spp == 4


@pytest.mark.mitsuba
def test_samples_out_writes_the_layout_of_data_samples(tmp_path: Path) -> None:
    """``--samples-out DIR``: one single-part file per level, the reference colour only;
    colour float32, the features half (what data/samples holds)."""
    from mcdenoise.io import probe_exr

    spec(tmp_path / "scenes", "ball")
    out, samples = tmp_path / "data", tmp_path / "samples"
    r = run(
        "render", str(tmp_path / "scenes"), "-o", str(out), *TINY, "--samples-out", str(samples)
    )
    assert r.exit_code == 0, r.output + r.stderr
    assert f"samples layout: 3 file(s) in {samples}" in r.output
    files = sorted(p.relative_to(samples).as_posix() for p in samples.rglob("*.exr"))
    assert files == ["ball_spp1.exr", "ball_spp4.exr", "ref/ball.exr"]
    level = load_buffers(out / "ball.exr", part="spp4")
    flat = load_buffers(samples / "ball_spp4.exr")
    assert flat.spp == 4 and sorted(flat.names()) == sorted(level.names())
    assert torch_equal(flat["color"], level["color"])
    assert flat.attributes["mcdenoise:seed"] == level.attributes["mcdenoise:seed"]
    assert str(flat.attributes["mitsuba:version"]).startswith("3.")
    (part,) = probe_exr(samples / "ball_spp4.exr")
    types = {c.name: c.pixel_type for c in part.channels}
    assert types["R"] == types["color_var.R"] == "float" and types["albedo.R"] == "half"
    ref = load_buffers(samples / "ref" / "ball.exr")
    assert ref.names() == ["color"] and ref.spp == 8


def torch_equal(a, b) -> bool:
    return bool((a == b).all())

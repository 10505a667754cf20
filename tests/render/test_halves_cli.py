"""``mcdenoise render --halves/--no-halves`` on the command line (16×16, scalar_rgb)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from click.testing import CliRunner
from mcdenoise_cli.main import main
from scene_specs import BALL_SCENE

from mcdenoise.io import load_buffers

TINY = ("--res", "16", "--spp", "1,4", "--ref-spp", "4", "--variant", "scalar_rgb")


def run(*args: str):
    return CliRunner().invoke(main, list(args), catch_exceptions=False)


@pytest.mark.mitsuba
def test_halves_by_default_and_a_folder_keeps_its_choice(tmp_path: Path) -> None:
    pytest.importorskip("mitsuba")
    (tmp_path / "ball.toml").write_text(BALL_SCENE.format(name="ball"), encoding="utf-8")
    out = tmp_path / "out"
    r = run("render", str(tmp_path / "ball.toml"), "-o", str(out), *TINY)
    assert r.exit_code == 0, r.output + r.stderr
    fb = load_buffers(out / "ball.exr", part="spp4")
    assert torch.equal(fb["color"], (fb["color_a"] + fb["color_b"]) / 2)
    assert json.loads((out / "manifest.json").read_text())["settings"]["halves"] is True
    r = run("render", str(tmp_path / "ball.toml"), "-o", str(out), *TINY, "--no-halves")
    err = r.stderr.strip()
    assert r.exit_code != 0 and len(err.splitlines()) == 1 and "--no-halves" in err, err
    plain = tmp_path / "plain"
    r = run("render", str(tmp_path / "ball.toml"), "-o", str(plain), *TINY, "--no-halves")
    assert r.exit_code == 0, r.output + r.stderr
    assert "color_a" not in load_buffers(plain / "ball.exr", part="spp4")


@pytest.mark.mitsuba
def test_layout_oidn_also_writes_the_oidn_training_layout(tmp_path: Path) -> None:
    pytest.importorskip("mitsuba")
    (tmp_path / "ball.toml").write_text(BALL_SCENE.format(name="ball"), encoding="utf-8")
    out = tmp_path / "out"
    r = run("render", str(tmp_path / "ball.toml"), "-o", str(out), *TINY, "--layout", "oidn")
    assert r.exit_code == 0, r.output + r.stderr
    assert (out / "oidn" / "ball_ref.hdr.exr").is_file() and "oidn layout:" in r.output
    r = run("render", str(tmp_path / "ball.toml"), "-o", str(tmp_path / "s"), *TINY,
            "--layout", "oidn", "--frames", "2")  # fmt: skip
    assert r.exit_code != 0 and "--layout oidn is for still images" in r.output + r.stderr

"""``mcdenoise train`` and ``mcdenoise denoise --model`` from the command line."""

from __future__ import annotations

from pathlib import Path

import torch
from click.testing import CliRunner
from mcdenoise_cli.main import main

from mcdenoise.io import load_buffers

TINY = ["-s", "kernel=5", "-s", "patch=16", "-s", "margin=2", "-s", "batch=2", "-s", "threads=1"]


def test_train_then_denoise_with_the_run(tiny_dataset: Path, tmp_path: Path) -> None:
    run = tmp_path / "runs" / "xbf"
    r = CliRunner().invoke(
        main,
        [
            "train",
            "--model",
            "kalantari-xbf",
            "--data",
            str(tiny_dataset),
            "--out",
            str(run),
            "--steps",
            "2",
            "-s",
            "epoch_steps=2",
            "--quiet",
            *TINY,
        ],
    )
    assert r.exit_code == 0, r.output
    assert "trained kalantari-xbf for 2 steps" in r.output
    assert (run / "model.pt").is_file() and (run / "config.json").is_file()
    src = tiny_dataset / "cornell.exr"
    out = tmp_path / "out.exr"
    r = CliRunner().invoke(
        main,
        [
            "denoise",
            str(src),
            "--part",
            "spp4",
            "--method",
            "kalantari-xbf",
            "--model",
            str(run),
            "-o",
            str(out),
        ],
    )
    assert r.exit_code == 0, r.output
    b = load_buffers(out)
    assert b.attributes["mcdenoise:method"] == "kalantari-xbf"
    assert str(run) in b.attributes["mcdenoise:params"]
    assert bool(torch.isfinite(b["color"]).all())
    # --model alone picks the method from the model file
    out2 = tmp_path / "out2.exr"
    r = CliRunner().invoke(
        main, ["denoise", str(src), "--part", "spp4", "--model", str(run), "-o", str(out2)]
    )
    assert r.exit_code == 0, r.output
    assert torch.equal(load_buffers(out2)["color"], b["color"])
    # resuming a finished run is a no-op that still reports
    r = CliRunner().invoke(main, ["train", "--out", str(run), "--resume", "--quiet"])
    assert r.exit_code == 0, r.output


def test_bad_model_paths_and_flags_are_one_line_errors(samples_dir: Path, tmp_path: Path) -> None:
    src = samples_dir / "cornell_spp4.exr"
    r = CliRunner().invoke(
        main,
        [
            "denoise",
            str(src),
            "--method",
            "kalantari-xbf",
            "--model",
            str(tmp_path / "nope"),
            "-o",
            str(tmp_path / "o.exr"),
        ],
    )
    assert r.exit_code == 1 and "nope" in r.output and "Traceback" not in r.output
    assert len(r.output.strip().splitlines()) == 1
    assert not (tmp_path / "o.exr").exists()
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a model")
    r = CliRunner().invoke(
        main, ["denoise", str(src), "--method", "kalantari-nlm", "--model", str(bad)]
    )
    assert r.exit_code == 1 and "bad.pt" in r.output and "truncated or corrupt" in r.output
    r = CliRunner().invoke(main, ["denoise", str(src), "--method", "nlm", "--model", str(bad)])
    assert r.exit_code == 2 and "learned" in r.output
    r = CliRunner().invoke(main, ["train", "--data", str(tmp_path), "--out", str(tmp_path / "r")])
    assert r.exit_code == 1 and "no input EXR" in r.output
    r = CliRunner().invoke(main, ["train", "--out", str(tmp_path / "r"), "-s", "steps=abc"])
    assert r.exit_code == 1 and "'steps'" in r.output

"""Tests for mcdenoise/eval/evaluate.py: matching, noisy inputs, file-level evaluation."""

from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from mcdenoise.errors import InputError
from mcdenoise.eval import evaluate, match_prefix, run_eval
from mcdenoise.eval import metrics as M
from mcdenoise.eval.matching import scan_exr
from mcdenoise.io.atomic import TMP_PREFIX
from mcdenoise.io.exr_write import write_exr

H, W = 12, 16


def image(seed: int, scale: float = 1.0, h: int = H, w: int = W) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (scale * rng.gamma(2.0, 0.4, size=(3, h, w))).astype(np.float32)


def save(path: Path, rgb: np.ndarray, **attrs) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    attributes = {f"mcdenoise:{k}": v for k, v in attrs.items()}
    write_exr(path, {c: rgb[i] for i, c in enumerate("RGB")}, attributes=attributes)
    return path


def read_color(path: Path) -> np.ndarray:
    from mcdenoise.io import load_buffers

    return load_buffers(path)["color"].numpy()


@pytest.fixture
def scenes(tmp_path: Path) -> dict[str, Path]:
    """Two scenes whose names share a prefix, noisy inputs, and denoised outputs."""
    ref = {"cornell": image(1), "cornell_glossy": image(2)}
    p = {
        "ref_dir": tmp_path / "ref",
        "ref_cornell": save(tmp_path / "ref" / "cornell.exr", ref["cornell"]),
        "ref_glossy": save(tmp_path / "ref" / "cornell_glossy.exr", ref["cornell_glossy"]),
    }
    rng = np.random.default_rng(9)
    noisy = {
        k: (v * (1 + 0.7 * rng.standard_normal(v.shape))).astype(np.float32) for k, v in ref.items()
    }
    p["noisy_cornell"] = save(tmp_path / "in" / "cornell_spp4.exr", noisy["cornell"])
    p["noisy_glossy"] = save(tmp_path / "in" / "cornell_glossy_spp16.exr", noisy["cornell_glossy"])
    out = tmp_path / "out"
    p["out_dir"] = out
    p["nlm"] = save(
        out / "cornell_spp4_nlm.exr",
        (ref["cornell"] + 0.02).astype(np.float32),
        method="nlm",
        source=str(p["noisy_cornell"].resolve()),
        seconds=0.5,
        device="cpu",
        params='{"h": 0.1}',
    )
    p["bilateral"] = save(
        out / "cornell_glossy_spp16_bilateral.exr",
        (ref["cornell_glossy"] * 1.05).astype(np.float32),
        method="bilateral",
        source=str(p["noisy_glossy"].resolve()),
        seconds=0.25,
    )
    return p


def test_match_prefix_longest_at_word_boundary():
    refs = ["cornell", "cornell_glossy", "veach"]
    assert match_prefix("cornell_spp16_nlm", refs) == "cornell"
    assert match_prefix("cornell_glossy_spp4_nlm", refs) == "cornell_glossy"
    assert match_prefix("cornell", refs) == "cornell"
    assert match_prefix("cornellbox_nlm", refs) is None
    assert match_prefix("bathroom_nlm", refs) is None


def test_scan_skips_temp_files_and_other_suffixes(tmp_path):
    save(tmp_path / "a.exr", image(0))
    save(tmp_path / "b.EXR", image(0))
    (tmp_path / f"{TMP_PREFIX}xyz.exr").write_bytes(b"partial")
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "sub").mkdir()
    save(tmp_path / "sub" / "c.exr", image(0))
    assert [p.name for p in scan_exr(tmp_path)] == ["a.exr", "b.EXR"]
    with pytest.raises(InputError, match="not found"):
        scan_exr(tmp_path / "missing.exr")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match=r"no \*\.exr output in folder"):
        scan_exr(empty, what="output")


def test_folder_reference_matches_longest_prefix_and_finds_noisy_inputs(scenes):
    result = evaluate(scenes["ref_dir"], [scenes["out_dir"]])
    assert result.references == {
        "cornell": str(scenes["ref_cornell"]),
        "cornell_glossy": str(scenes["ref_glossy"]),
    }
    rows = [(r.scene, r.role, r.method, Path(r.file).name) for r in result.records]
    assert rows == [
        ("cornell", "noisy", "noisy", "cornell_spp4.exr"),
        ("cornell", "output", "nlm", "cornell_spp4_nlm.exr"),
        ("cornell_glossy", "noisy", "noisy", "cornell_glossy_spp16.exr"),
        ("cornell_glossy", "output", "bilateral", "cornell_glossy_spp16_bilateral.exr"),
    ]
    nlm = result.records[1]
    assert nlm.input == str(scenes["noisy_cornell"].resolve())
    assert (nlm.spp, nlm.seconds, nlm.device, nlm.params) == (4, 0.5, "cpu", '{"h": 0.1}')
    assert result.records[0].spp == 4 and result.records[2].spp == 16  # from the file names
    # numbers equal metrics recomputed from the EXRs themselves
    ref = read_color(scenes["ref_cornell"])
    for rec in result.scene_records("cornell"):
        img = read_color(Path(rec.file))
        assert rec.metrics["relmse"] == pytest.approx(M.relmse(img, ref), rel=1e-12)
        assert rec.metrics["ssim"] == pytest.approx(M.ssim(img, ref), rel=1e-12)
    noisy = result.records[0]
    assert nlm.relmse_ratio == pytest.approx(nlm.metrics["relmse"] / noisy.metrics["relmse"])
    assert nlm.relmse_ratio < 1


def test_output_without_a_matching_reference_is_an_error_naming_it(scenes):
    stray = save(scenes["out_dir"] / "bathroom_spp4_nlm.exr", image(3), method="nlm")
    with pytest.raises(InputError) as err:
        evaluate(scenes["ref_dir"], [scenes["out_dir"]])
    assert str(stray) in str(err.value) and "\n" not in str(err.value)


def test_single_reference_file_takes_every_output(scenes):
    result = evaluate(scenes["ref_cornell"], [scenes["nlm"]], metrics=["relmse", "psnr"])
    assert {r.scene for r in result.records} == {"cornell"}
    assert [r.method for r in result.records] == ["noisy", "nlm"]
    assert list(result.records[1].metrics) == ["relmse", "psnr"]


def test_size_mismatch_names_both_files_and_sizes(scenes, tmp_path):
    small = save(tmp_path / "o" / "cornell_small.exr", image(4, h=H, w=W - 2), method="x")
    with pytest.raises(InputError) as err:
        evaluate(scenes["ref_cornell"], [small])
    msg = str(err.value)
    assert str(small) in msg and str(scenes["ref_cornell"]) in msg
    assert f"{W - 2}x{H}" in msg and f"{W}x{H}" in msg


def test_missing_source_uses_inputs_and_notes_it(scenes, tmp_path):
    out = save(
        tmp_path / "o" / "cornell_spp4_oidn.exr",
        image(1) + 0.01,
        method="oidn",
        source=str(tmp_path / "gone" / "cornell_spp4.exr"),
    )
    plain = save(tmp_path / "o" / "cornell_spp4_mine.exr", image(1) + 0.03)  # no attributes
    fast = ["relmse", "psnr"]  # FLIP and SSIM are covered elsewhere
    r1 = evaluate(scenes["ref_dir"], [out], metrics=fast)
    assert [rec.method for rec in r1.records] == ["oidn"]
    assert r1.records[0].input is None and r1.records[0].relmse_ratio is None
    assert "not found" in r1.records[0].notes[0]
    r2 = evaluate(
        scenes["ref_dir"], [out, plain], inputs=[scenes["noisy_cornell"].parent], metrics=fast
    )
    rows = [(r.scene, r.method, Path(r.file).name) for r in r2.records]
    # the noisy input of the other scene was given too, so it is shown as well
    assert ("cornell", "noisy", "cornell_spp4.exr") in rows
    assert ("cornell", "oidn", "cornell_spp4_oidn.exr") in rows
    assert ("cornell", "mine", "cornell_spp4_mine.exr") in rows  # method from the file name
    assert ("cornell_glossy", "noisy", "cornell_glossy_spp16.exr") in rows
    oidn = next(r for r in r2.records if r.method == "oidn")
    assert oidn.input == str(scenes["noisy_cornell"]) and oidn.relmse_ratio is not None


def test_noisy_file_given_as_output_becomes_the_noisy_row(scenes):
    result = evaluate(scenes["ref_dir"], [scenes["noisy_cornell"], scenes["nlm"]], metrics=["mse"])
    assert [(r.role, r.method) for r in result.records] == [("noisy", "noisy"), ("output", "nlm")]


def test_nan_output_file_fails_in_every_report_format(scenes, tmp_path):
    bad = image(1)
    bad[0, 3, 3] = np.nan
    bad_path = save(
        scenes["out_dir"] / "cornell_spp4_broken.exr",
        bad,
        method="broken",
        source=str(scenes["noisy_cornell"].resolve()),
    )
    same = save(scenes["out_dir"] / "cornell_spp4_same.exr", image(1), method="copy")
    result, paths = run_eval(
        scenes["ref_dir"],
        [scenes["out_dir"]],
        tmp_path / "report",
        metrics=["relmse", "smape", "mse", "psnr"],  # FLIP/SSIM: see the test above
    )
    broken = next(r for r in result.records if r.file == str(bad_path))
    assert broken.failed and broken.bad_pixels == 1
    data = json.loads(paths["json"].read_text(), parse_constant=lambda c: pytest.fail(c))
    rec = next(r for r in data["records"] if r["file"] == str(bad_path))
    assert rec["failed"] and rec["bad_pixels"] == 1 and rec["metrics"]["relmse"] is None
    copy = next(r for r in data["records"] if r["file"] == str(same))
    assert copy["metrics"]["psnr"] == "inf" and copy["metrics"]["relmse"] == 0.0
    row = next(r for r in csv.DictReader(paths["csv"].open()) if r["file"] == str(bad_path))
    assert row["failed"] == "true" and row["bad_pixels"] == "1"
    page = paths["html"].read_text(encoding="utf-8")
    assert "FAILED: 1 non-finite pixel" in page
    assert [p for p in (tmp_path / "report").rglob("*") if p.name.startswith(TMP_PREFIX)] == []
    # numbers in the JSON equal metrics recomputed from the EXR files
    for r in data["records"]:
        if r["failed"]:
            continue
        ref = read_color(Path(result.references[r["scene"]]))
        img = read_color(Path(r["file"]))
        for name in ("relmse", "smape", "mse"):
            assert r["metrics"][name] == pytest.approx(getattr(M, name)(img, ref), rel=1e-12)
        psnr = M.psnr(img, ref)
        assert r["metrics"]["psnr"] == ("inf" if math.isinf(psnr) else pytest.approx(psnr))


def test_output_equal_to_reference_is_refused(scenes):
    with pytest.raises(InputError, match="is the reference"):
        evaluate(scenes["ref_dir"], [scenes["ref_cornell"]])


def test_missing_paths_are_input_errors(scenes, tmp_path):
    with pytest.raises(InputError, match="reference not found"):
        evaluate(tmp_path / "nope.exr", [scenes["nlm"]])
    with pytest.raises(InputError, match="output not found"):
        evaluate(scenes["ref_dir"], [tmp_path / "nope.exr"])


def test_paths_may_be_strings_or_pathlike(scenes):
    result = evaluate(os.fspath(scenes["ref_dir"]), [os.fspath(scenes["nlm"])], metrics=["mse"])
    assert [r.method for r in result.records] == ["noisy", "nlm"]

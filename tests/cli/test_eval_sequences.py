"""``mcdenoise eval`` on sequences: folders of frames, per-frame and temporal metrics."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
from fast_methods import run_cli

from mcdenoise.errors import InputError
from mcdenoise.eval import (
    EvalOptions,
    evaluate_sequence_arrays,
    evaluate_sequences,
    temporal_relmse,
)
from mcdenoise.eval.temporal_metrics import TEMPORAL_METRICS
from mcdenoise.io import exr_write
from mcdenoise.io.exr_write import ExrPartData

H, W = 12, 14
FRAMES = 5


def ref_frames(n: int = FRAMES) -> list[np.ndarray]:
    """A square sliding one pixel per frame over a textured background."""
    rng = np.random.default_rng(0)
    base = rng.gamma(2.0, 0.25, size=(3, H, W))
    out = []
    for t in range(n):
        f = base.copy()
        f[:, 3:7, 2 + t : 6 + t] += 1.0
        out.append(f.astype(np.float32))
    return out


def write_exr(path: Path, channels: dict, **kw) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    exr_write.write_exr(path, channels, **kw)


def write_exr_parts(path: Path, parts: list) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    exr_write.write_exr_parts(path, parts)


def rgb(image: np.ndarray) -> dict[str, np.ndarray]:
    return {c: image[i] for i, c in enumerate("RGB")}


def frame_attrs(t: int, **extra) -> dict:
    return {"mcdenoise:scene": "slide", "mcdenoise:frame": t, **extra}


def write_sequence(root: Path, n: int = FRAMES) -> tuple[Path, list[np.ndarray]]:
    """``root/ref/frame_000t.exr`` and noisy ``root/frame_000t.exr`` (parts spp4, spp16),
    in the layout of ``mcdenoise render --frames``."""
    refs = ref_frames(n)
    rng = np.random.default_rng(1)
    for t, r in enumerate(refs):
        write_exr(root / "ref" / f"frame_{t:04d}.exr", rgb(r), attributes=frame_attrs(t))
        parts = [
            ExrPartData(
                name=f"spp{s}",
                channels=rgb((r * (1 + a * rng.standard_normal(r.shape))).astype(np.float32)),
                attributes=frame_attrs(t, **{"mcdenoise:spp": s}),
            )
            for s, a in ((4, 0.8), (16, 0.4))
        ]
        write_exr_parts(root / f"frame_{t:04d}.exr", parts)
    return root / "ref", refs


def write_outputs(
    folder: Path, seq: Path, images: list[np.ndarray], method: str, **attrs
) -> list[np.ndarray]:
    """Denoised frames as ``mcdenoise denoise SEQ_DIR`` writes them (header provenance)."""
    for t, img in enumerate(images):
        write_exr(
            folder / f"frame_{t:04d}.exr",
            rgb(img.astype(np.float32)),
            attributes={
                "mcdenoise:method": method,
                "mcdenoise:source": str((seq / f"frame_{t:04d}.exr").resolve()),
                "mcdenoise:source_part": "spp4",
                "mcdenoise:seconds": 0.25,
                **attrs,
            },
        )
    return images


@pytest.fixture
def sequence(tmp_path: Path) -> dict:
    seq = tmp_path / "slide"
    ref_dir, refs = write_sequence(seq)
    rng = np.random.default_rng(2)
    flicker = [r * (1 + 0.1 * rng.standard_normal(r.shape)) for r in refs]
    stable = [r * 1.1 for r in refs]  # biased by 10 %, the same way in every frame
    write_outputs(tmp_path / "out_flicker", seq, flicker, "flicker")
    write_outputs(tmp_path / "out_stable", seq, stable, "stable")
    return {"seq": seq, "ref": ref_dir, "refs": refs, "flicker": flicker, "stable": stable}


def one_line_error(result) -> str:
    assert result.exit_code not in (0, None), result.output
    err = result.stderr.strip()
    assert "Traceback" not in result.output + err
    assert len(err.splitlines()) == 1, err
    return err


def test_eval_of_sequences_writes_per_frame_and_temporal_metrics(sequence, tmp_path):
    rep = tmp_path / "rep"
    r = run_cli(
        "eval",
        tmp_path / "out_flicker",
        tmp_path / "out_stable",
        "--ref",
        sequence["ref"],
        "-o",
        rep,
        "--metrics",
        "relmse,ssim,trelmse,tpsnr,trmae",
    )
    assert r.exit_code == 0, r.output
    out = r.stdout
    assert "temporal relMSE" in out and "tPSNR (dB)" in out and "tRMAE" in out
    assert "slide: per frame (* = warm-up)" in out
    assert "frame_0000 *" in out and "frame_0001 *" in out and "frame_0002 *" not in out

    data = json.loads((rep / "results.json").read_text())
    assert data["sequences"]["warmup"] == 2
    assert set(data["metrics"]) == {"relmse", "ssim", "trelmse", "tpsnr", "trmae"}
    assert data["metrics"]["tpsnr"]["temporal"] is True
    assert "Noisebase" in data["metrics"]["trmae"]["definition"]
    recs = {rec["method"]: rec for rec in data["records"]}
    assert set(recs) == {"noisy", "flicker", "stable"}
    assert [rec["method"] for rec in data["records"]] == ["noisy", "flicker", "stable"]
    noisy, flicker, stable = recs["noisy"], recs["flicker"], recs["stable"]
    assert noisy["role"] == "noisy" and noisy["spp"] == 4 and noisy["file"].endswith("#spp4")
    assert flicker["input"] == noisy["file"] and flicker["seconds"] == pytest.approx(0.25)
    assert flicker["sequence"]["frame_count"] == FRAMES
    assert [f["warmup"] for f in flicker["sequence"]["frames"]] == [True, True, False, False, False]
    # the flicker is unstable, the bias is not; per frame both are about as wrong
    m_f, m_s = flicker["metrics"], stable["metrics"]
    assert m_f["trelmse"] > 3 * m_s["trelmse"] and m_f["tpsnr"] < m_s["tpsnr"]
    assert m_f["relmse"] == pytest.approx(m_s["relmse"], rel=0.3)
    assert noisy["metrics"]["trelmse"] > m_f["trelmse"]
    # the headline is over frames past the warm-up; "all" equals the plain definition
    frames = flicker["sequence"]["frames"]
    assert frames[0]["metrics"]["trelmse"] is None
    assert m_f["relmse"] == pytest.approx(np.mean([f["metrics"]["relmse"] for f in frames[2:]]))
    assert m_f["trelmse"] == pytest.approx(np.mean([f["metrics"]["trelmse"] for f in frames[3:]]))
    all_t = flicker["sequence"]["all_metrics"]["trelmse"]
    assert all_t == pytest.approx(temporal_relmse(sequence["flicker"], sequence["refs"]), rel=1e-5)
    assert flicker["sequence"]["warmup_metrics"]["relmse"] == pytest.approx(
        np.mean([f["metrics"]["relmse"] for f in frames[:2]])
    )

    with open(rep / "frames.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 3 * FRAMES
    assert rows[0]["frame"] == "frame_0000" and rows[0]["trelmse"] == ""
    with open(rep / "results.csv", newline="") as fh:
        assert "trelmse" in next(csv.reader(fh))
    page = (rep / "report.html").read_text()
    assert "Per frame" in page and "warm-up" in page and "Sequences" in page
    assert TEMPORAL_METRICS["trmae"].definition.split(";")[0].replace("|", "") in page.replace(
        "|", ""
    )


def test_warmup_zero_averages_every_frame(sequence, tmp_path):
    result = evaluate_sequences(
        sequence["ref"], [tmp_path / "out_flicker"], EvalOptions(metrics=["trelmse"], warmup=0)
    )
    (rec,) = [r for r in result.records if r.method == "flicker"]
    assert rec.metrics["trelmse"] == pytest.approx(
        temporal_relmse(sequence["flicker"], sequence["refs"]), rel=1e-5
    )
    assert rec.sequence is not None and rec.sequence.warmup_metrics["trelmse"] is None
    r = run_cli(
        "eval",
        tmp_path / "out_flicker",
        "--ref",
        sequence["ref"],
        "-o",
        tmp_path / "rep",
        "--warmup",
        "0",
        "--metrics",
        "trelmse",
    )
    assert r.exit_code == 0 and "*" not in r.stdout.split("per frame")[1].split("\n", 1)[1]


def test_output_lacking_a_frame_is_one_line(sequence, tmp_path):
    (tmp_path / "out_stable" / "frame_0003.exr").unlink()
    msg = one_line_error(run_cli("eval", tmp_path / "out_stable", "--ref", sequence["ref"]))
    assert "out_stable lacks frame_0003.exr" in msg and "5 frames (frame_0000 to frame_0004)" in msg


def test_gap_in_the_reference_is_one_line(sequence, tmp_path):
    (sequence["ref"] / "frame_0002.exr").unlink()
    msg = one_line_error(run_cli("eval", tmp_path / "out_stable", "--ref", sequence["ref"]))
    assert "has a gap: frame_0002.exr missing between frame_0001.exr and frame_0003.exr" in msg


def test_size_mismatch_is_one_line(sequence, tmp_path):
    small = np.ones((3, H - 2, W), np.float32)
    write_outputs(
        tmp_path / "out_stable", sequence["seq"], [*sequence["stable"][:2], small], "stable"
    )
    msg = one_line_error(run_cli("eval", tmp_path / "out_stable", "--ref", sequence["ref"]))
    assert "frame_0002.exr is 14x10 but reference" in msg and "is 14x12" in msg
    # a reference frame of another size than the first
    write_exr(sequence["ref"] / "frame_0004.exr", rgb(np.ones((3, H, W + 1), np.float32)))
    write_outputs(tmp_path / "out_b", sequence["seq"], sequence["stable"][:4], "b")
    write_exr(tmp_path / "out_b" / "frame_0004.exr", rgb(np.ones((3, H, W + 1), np.float32)))
    msg = one_line_error(run_cli("eval", tmp_path / "out_b", "--ref", sequence["ref"]))
    assert "frame_0004.exr is 15x12 but" in msg and "must have one size" in msg


def test_frames_of_another_sequence_are_refused_unless_forced(sequence, tmp_path):
    shifted = tmp_path / "out_shifted"
    write_outputs(shifted, sequence["seq"], sequence["stable"], "stable")
    # frame 4's output claims to come from frame 3's noisy file (which records frame 3)
    write_exr(
        shifted / "frame_0004.exr",
        rgb(sequence["stable"][4]),
        attributes={
            "mcdenoise:method": "stable",
            "mcdenoise:source": str((sequence["seq"] / "frame_0003.exr").resolve()),
            "mcdenoise:source_part": "spp4",
        },
    )
    msg = one_line_error(run_cli("eval", shifted, "--ref", sequence["ref"]))
    assert "frame '3'" in msg and "frame '4'" in msg and "--force" in msg
    r = run_cli("eval", shifted, "--ref", sequence["ref"], "--force", "-o", tmp_path / "rep")
    assert r.exit_code == 0 and "warning" in r.stderr


def test_a_file_as_output_and_temporal_metrics_on_stills_are_one_line(sequence, tmp_path):
    msg = one_line_error(
        run_cli("eval", tmp_path / "out_stable" / "frame_0000.exr", "--ref", sequence["ref"])
    )
    assert "is a file, but the reference" in msg and "folder of frames" in msg
    still_ref = sequence["ref"] / "frame_0000.exr"
    msg = one_line_error(
        run_cli(
            "eval",
            tmp_path / "out_stable" / "frame_0000.exr",
            "--ref",
            still_ref,
            "--metrics",
            "relmse,tpsnr",
        )
    )
    assert "'tpsnr' is temporal: it needs sequences" in msg


def test_one_frame_sequence_reports_temporal_metrics_as_undefined(tmp_path):
    seq = tmp_path / "one"
    ref_dir, refs = write_sequence(seq, n=1)
    write_outputs(tmp_path / "out", seq, [refs[0] * 1.05], "m")
    rep = tmp_path / "rep"
    r = run_cli("eval", tmp_path / "out", "--ref", ref_dir, "-o", rep, "--warmup", "0")
    assert r.exit_code == 0, r.output
    data = json.loads((rep / "results.json").read_text())
    (rec,) = [x for x in data["records"] if x["method"] == "m"]
    assert rec["metrics"]["trelmse"] is None and rec["metrics"]["relmse"] > 0
    assert "1 frame has no frame pair" in rec["unavailable"]["trelmse"]
    assert "n/a" in (rep / "report.html").read_text()


def test_noisy_folder_given_as_output_is_the_noisy_row(sequence, tmp_path):
    result = evaluate_sequences(
        sequence["ref"], [sequence["seq"], tmp_path / "out_stable"], EvalOptions(metrics=["relmse"])
    )
    # the noisy frames are read with the part the outputs were made from (spp4), once
    assert [r.method for r in result.records] == ["noisy", "stable"]
    assert result.records[1].relmse_ratio is not None and result.records[1].relmse_ratio < 1


def test_array_sequences_and_suffixed_frames(tmp_path, sequence):
    refs = sequence["refs"]
    res = evaluate_sequence_arrays(
        refs, {"a": sequence["flicker"], "b": sequence["stable"]}, metrics=["relmse", "trelmse"]
    )
    assert [r.method for r in res.records] == ["a", "b"]
    assert res.records[0].metrics["trelmse"] > res.records[1].metrics["trelmse"]
    assert "per frame" in res.format_frames()
    with pytest.raises(InputError, match="has 2 frames but the reference has 5"):
        evaluate_sequence_arrays(refs, {"a": refs[:2]})
    # two methods in one folder, told apart by a suffix: two sequences
    both = tmp_path / "both"
    for t, (f, s) in enumerate(zip(sequence["flicker"], sequence["stable"])):
        write_exr(both / f"frame_{t:04d}_flicker.exr", rgb(f.astype(np.float32)))
        write_exr(both / f"frame_{t:04d}_stable.exr", rgb(s.astype(np.float32)))
    res = evaluate_sequences(sequence["ref"], [both], EvalOptions(metrics=["trelmse"]))
    assert sorted(r.method for r in res.records) == ["flicker", "stable"]
    assert not math.isnan(res.records[0].metrics["trelmse"])


def test_noisy_frames_from_input_folder_when_outputs_record_no_source(sequence, tmp_path):
    bare = tmp_path / "bare"
    for t, img in enumerate(sequence["stable"]):
        write_exr(bare / f"frame_{t:04d}.exr", rgb(img.astype(np.float32)))
    without = evaluate_sequences(sequence["ref"], [bare], EvalOptions(metrics=["relmse"]))
    assert [r.method for r in without.records] == ["bare"]  # the folder names the method
    r = run_cli(
        "eval",
        bare,
        "--ref",
        sequence["ref"],
        "-i",
        sequence["seq"],
        "-o",
        tmp_path / "rep",
        "--metrics",
        "relmse,trelmse",
    )
    assert r.exit_code == 0, r.output
    data = json.loads((tmp_path / "rep" / "results.json").read_text())
    noisy, out = data["records"]
    assert noisy["role"] == "noisy" and noisy["spp"] == 4  # the first part: spp4
    assert out["input"] == noisy["file"] and out["relmse_ratio"] < 0.1


def test_a_nan_frame_fails_its_sequence_in_the_report(sequence, tmp_path):
    broken = [f.copy() for f in sequence["stable"]]
    broken[3][0, 2, 2] = np.nan
    write_outputs(tmp_path / "out_broken", sequence["seq"], broken, "broken")
    rep = tmp_path / "rep"
    r = run_cli("eval", tmp_path / "out_broken", "--ref", sequence["ref"], "-o", rep)
    # the report is written, and eval exits with 1 (--keep-going: 0; issue 33 item 7)
    assert r.exit_code == 1 and "FAILED" in r.stderr, r.output
    assert "FAILED: 1 of 5 frames failed; 1 non-finite pixel(s)" in r.stdout
    data = json.loads((rep / "results.json").read_text())
    (rec,) = [x for x in data["records"] if x["method"] == "broken"]
    assert rec["failed"] and rec["metrics"]["trelmse"] is None and rec["bad_pixels"] == 1
    frames = rec["sequence"]["frames"]
    assert frames[3]["failed"] and frames[2]["metrics"]["relmse"] is not None
    assert "FAILED" in (rep / "report.html").read_text()

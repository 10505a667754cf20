"""Tests for mcdenoise/eval/eval_report.py (and results.py): JSON, CSV and HTML on in-memory images."""

from __future__ import annotations

import csv
import json
import math
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from mcdenoise.errors import McdenoiseError
from mcdenoise.eval import eval_report as report
from mcdenoise.eval import evaluate_arrays, write_report
from mcdenoise.eval import metrics as M
from mcdenoise.eval.results import EvalRecord, EvalResult, decode_float, jsonable
from mcdenoise.io.atomic import TMP_PREFIX


def _no_constants(name: str):
    raise AssertionError(f"bare {name} in JSON")


def load_json(path: Path) -> dict:
    return json.loads(path.read_text(encoding="utf-8"), parse_constant=_no_constants)


def scene_images(h: int = 24, w: int = 32):
    rng = np.random.default_rng(7)
    yy, xx = np.mgrid[0:h, 0:w]
    ref = np.stack([0.5 + 0.4 * np.sin(xx / 3.0), 0.2 + 0.5 * yy / h, np.full((h, w), 0.1)]).astype(
        np.float32
    )
    ref[:, :4, :4] = 0.0  # zero reference pixels
    noisy = np.clip(ref * (1 + 0.9 * rng.standard_normal(ref.shape)), 0, None).astype(np.float32)
    good = (ref + 0.01 * rng.standard_normal(ref.shape)).astype(np.float32)
    blurry = (ref + 0.05 * rng.standard_normal(ref.shape)).astype(np.float32)
    broken = good.copy()
    broken[0, 5, 6] = np.nan
    broken[1, h - 1, 3] = np.inf
    return ref, noisy, {"good": good, "blurry": blurry, "broken": broken, "perfect": ref.copy()}


@pytest.fixture(scope="module")
def result_and_arrays():
    ref, noisy, outputs = scene_images()
    info = {"noisy": {"spp": 4}, "good": {"method": "nlm", "seconds": 0.25, "device": "cpu"}}
    result = evaluate_arrays(ref, outputs, noisy=noisy, scene="cornell", info=info)
    return result, ref, noisy, outputs


@pytest.fixture(scope="module")
def written(result_and_arrays, tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    paths = write_report(result_and_arrays[0], out)
    return paths, out


def test_records_follow_the_arrays(result_and_arrays):
    result, ref, noisy, outputs = result_and_arrays
    assert [r.file for r in result.records] == ["noisy", "good", "blurry", "broken", "perfect"]
    by = {r.file: r for r in result.records}
    assert by["noisy"].role == "noisy" and by["noisy"].method == "noisy"
    assert by["good"].method == "nlm" and by["good"].seconds == 0.25 and by["good"].spp == 4
    assert by["blurry"].method == "blurry" and by["blurry"].input == "noisy"
    for name, image in [("noisy", noisy), *outputs.items()]:
        rec = by[name]
        if name == "broken":
            continue
        assert rec.metrics["relmse"] == pytest.approx(M.relmse(image, ref), rel=1e-12)
        assert rec.metrics["psnr"] == pytest.approx(M.psnr(image, ref), rel=1e-12)
    assert by["noisy"].relmse_ratio == 1.0
    assert by["good"].relmse_ratio == pytest.approx(
        M.relmse(outputs["good"], ref) / M.relmse(noisy, ref)
    )
    assert by["good"].relmse_ratio < by["blurry"].relmse_ratio < 1.0
    assert by["perfect"].metrics["psnr"] == math.inf
    assert by["broken"].failed and by["broken"].bad_pixels == 2
    assert by["broken"].relmse_ratio is None


def test_all_report_files_written_and_no_temp_files(written):
    paths, out = written
    for key in ("json", "csv", "html"):
        assert paths[key].is_file() and paths[key].stat().st_size > 0
    assert paths["images"].is_dir() and any(paths["images"].glob("*.png"))
    leftovers = [p for p in out.rglob("*") if p.name.startswith(TMP_PREFIX)]
    assert leftovers == []


def test_json_is_strict_and_matches_recomputed_metrics(written, result_and_arrays):
    paths, _ = written
    _, ref, noisy, outputs = result_and_arrays
    data = load_json(paths["json"])
    assert data["schema"] == "mcdenoise.eval/1"
    assert data["references"] == {"cornell": "reference"}
    assert data["metrics"]["relmse"]["epsilon"] == 0.01
    assert "linear" in data["metrics"]["relmse"]["space"]
    assert data["metrics"]["psnr"]["space"].startswith("sRGB")
    images = {"noisy": noisy, **outputs}
    for rec in data["records"]:
        if rec["failed"]:
            continue
        image = images[rec["file"]]
        for name in ("relmse", "smape", "mse", "psnr", "ssim"):
            expected = getattr(M, name)(image, ref)
            got = decode_float(rec["metrics"][name])
            assert got == pytest.approx(expected, rel=1e-12), (rec["file"], name)
    perfect = next(r for r in data["records"] if r["file"] == "perfect")
    assert perfect["metrics"]["psnr"] == "inf"  # documented encoding of +inf


def test_failed_output_is_marked_in_every_format(written):
    paths, _ = written
    data = load_json(paths["json"])
    broken = next(r for r in data["records"] if r["file"] == "broken")
    assert broken["failed"] is True and broken["bad_pixels"] == 2
    assert all(v is None for v in broken["metrics"].values())
    assert "2 non-finite pixel" in broken["reason"]
    rows = list(csv.DictReader(paths["csv"].open(encoding="utf-8")))
    row = next(r for r in rows if r["file"] == "broken")
    assert row["failed"] == "true" and row["bad_pixels"] == "2" and row["relmse"] == ""
    page = paths["html"].read_text(encoding="utf-8")
    assert re.search(r'<tr class="failed">.*?FAILED: 2 non-finite pixel', page)


def test_csv_matches_json(written):
    paths, _ = written
    data = load_json(paths["json"])
    rows = list(csv.DictReader(paths["csv"].open(encoding="utf-8")))
    assert len(rows) == len(data["records"])
    assert list(rows[0])[:8] == [
        "scene",
        "role",
        "method",
        "file",
        "input",
        "spp",
        "seconds",
        "device",
    ]
    for row, rec in zip(rows, data["records"]):
        assert row["file"] == rec["file"] and row["method"] == rec["method"]
        for name, value in rec["metrics"].items():
            assert decode_float(row[name]) == decode_float(value)
        assert decode_float(row["relmse_ratio"]) == decode_float(rec["relmse_ratio"])
    perfect = next(r for r in rows if r["file"] == "perfect")
    assert perfect["psnr"] == "inf"


class _Refs(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.refs: list[str] = []
        self.tags: set[str] = set()

    def handle_starttag(self, tag, attrs):
        self.tags.add(tag)
        for key, value in attrs:
            if key in ("src", "href") and value is not None:
                self.refs.append(value)


def test_html_references_only_existing_local_files(written):
    paths, out = written
    page = paths["html"].read_text(encoding="utf-8")
    parser = _Refs()
    parser.feed(page)
    assert parser.refs, "the report shows images"
    for ref in parser.refs:
        assert "://" not in ref and not ref.startswith("//"), ref
        assert (out / ref).is_file(), ref
    assert "script" not in parser.tags and "link" not in parser.tags
    assert "http://" not in page and "https://" not in page
    images = {p.name for p in paths["images"].iterdir()}
    assert images == {Path(r).name for r in parser.refs}  # nothing unreferenced either


def test_html_states_what_a_newcomer_needs(written, result_and_arrays):
    paths, _ = written
    page = paths["html"].read_text(encoding="utf-8")
    assert "<title>mcdenoise evaluation report</title>" in page
    assert "How to read this" in page
    assert "relMSE, SMAPE and MSE on linear HDR RGB; PSNR and SSIM on sRGB clamped to [0,1]" in page
    assert "ε = 0.01" in page
    assert f"version {result_and_arrays[0].version}" in page
    assert "Scene: cornell" in page
    assert "per-pixel relMSE" in page


def _cells(page: str, method: str) -> list[str]:
    row = re.search(rf"<tr[^>]*><td[^>]*>{method}<br>.*?</tr>", page).group(0)
    return re.findall(r'<td class="num[^"]*">(.*?)</td>', row)


def test_html_bolds_the_best_value_per_column(written):
    paths, _ = written
    page = paths["html"].read_text(encoding="utf-8")
    perfect = _cells(page, "perfect")  # input spp, relMSE, SMAPE, MSE, PSNR, SSIM, FLIP?, ...
    assert all("<b" in c for c in perfect[1:6]), perfect
    noisy = _cells(page, "noisy")
    assert not any("<b" in c for c in noisy[1:6]), noisy
    assert "\u221e" in perfect[4]  # PSNR infinity shown as ∞


def test_image_strip_has_noisy_outputs_reference_and_error_maps(written, result_and_arrays):
    paths, _ = written
    names = sorted(p.name for p in paths["images"].iterdir())
    result = result_and_arrays[0]
    n = len(result.records)
    assert sum(name.endswith("_relmse.png") for name in names) == n
    assert any(name.endswith("_reference.png") for name in names)
    assert any(name.endswith("_colorbar.png") for name in names)
    # small image: shown whole, so no overview thumbnail
    assert not any(name.endswith("_overview.png") for name in names)


def test_png_is_the_tonemapped_crop(tmp_path):
    import OpenImageIO as oiio

    rgb = np.zeros((3, 2, 3))
    rgb[0, 0, 0] = 1.0
    rgb[2, 1, 2] = 0.5
    report.write_png(tmp_path / "x.png", rgb)
    back = oiio.ImageBuf(str(tmp_path / "x.png")).get_pixels(oiio.UINT8)
    assert back.shape == (2, 3, 3)
    assert back[0, 0].tolist() == [255, 0, 0] and back[1, 2].tolist() == [0, 0, 128]
    assert [p.name for p in tmp_path.iterdir()] == ["x.png"]


def test_large_image_gets_a_crop_and_overview(tmp_path):
    rng = np.random.default_rng(3)
    ref = rng.random((3, 300, 280)).astype(np.float32)
    out = ref + 0.01
    result = evaluate_arrays(ref, {"den": out}, metrics=["relmse", "psnr"])
    preview = result.previews["scene"]
    assert preview.window[2:] == (256, 256) and preview.overview is not None
    assert preview.images["den"].shape == (3, 256, 256)
    paths = write_report(result, tmp_path)
    page = paths["html"].read_text(encoding="utf-8")
    assert "green box" in page and any(paths["images"].glob("*_overview.png"))
    data = load_json(paths["json"])
    assert list(data["records"][0]["metrics"]) == ["relmse", "psnr"]


def test_failed_write_leaves_no_temp_files_and_keeps_old_report(tmp_path, monkeypatch):
    ref, noisy, outputs = scene_images(8, 8)
    result = evaluate_arrays(ref, {"a": outputs["good"]}, noisy=noisy, metrics=["relmse"])
    paths = write_report(result, tmp_path)
    old_json = paths["json"].read_text()
    old_html = paths["html"].read_text()

    calls = {"n": 0}
    real = report.write_png

    def flaky(path, rgb, **options):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt  # e.g. Ctrl-C in the middle of the images
        real(path, rgb, **options)

    monkeypatch.setattr(report, "write_png", flaky)
    result2 = evaluate_arrays(ref, {"a": outputs["blurry"]}, noisy=noisy, metrics=["relmse"])
    with pytest.raises(KeyboardInterrupt):
        write_report(result2, tmp_path)
    assert [p for p in tmp_path.rglob("*") if p.name.startswith(TMP_PREFIX)] == []
    assert paths["html"].read_text() == old_html  # the page is written after its images
    assert json.loads(paths["json"].read_text()) != json.loads(old_json)  # json was replaced whole


def test_unwritable_report_folder_is_a_one_line_error(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    ref, _, outputs = scene_images(8, 8)
    result = evaluate_arrays(ref, {"a": outputs["good"]}, metrics=["mse"])
    with pytest.raises(McdenoiseError) as err:
        write_report(result, blocker / "report")
    assert "\n" not in str(err.value) and str(blocker) in str(err.value)


def test_jsonable_never_emits_bare_constants():
    obj = {
        "a": math.inf,
        "b": -math.inf,
        "c": math.nan,
        "d": np.float32(2.5),
        "e": (1, np.int64(2)),
    }
    text = json.dumps(jsonable(obj), allow_nan=False)
    assert json.loads(text, parse_constant=_no_constants) == {
        "a": "inf",
        "b": "-inf",
        "c": "nan",
        "d": 2.5,
        "e": [1, 2],
    }
    assert decode_float("inf") == math.inf and decode_float("") is None


def test_format_table_lists_every_record(result_and_arrays):
    text = result_and_arrays[0].format_table()
    lines = text.splitlines()
    assert len(lines) == 1 + len(result_and_arrays[0].records)
    assert "FAILED" in next(line for line in lines if " broken " in f" {line} ")
    assert "inf" in next(line for line in lines if "perfect" in line)


def test_format_table_tells_two_outputs_of_one_method_apart():
    ref, noisy, outputs = scene_images(8, 8)
    info = {
        "runs/a/out.exr": {"method": "kpcn", "spp": 4},
        "runs/b/out2.exr": {"method": "kpcn", "spp": 4},
        "other.exr": {"method": "nlm", "spp": 4},
    }
    images = {"runs/a/out.exr": outputs["good"], "runs/b/out2.exr": outputs["blurry"]}
    images["other.exr"] = outputs["good"]
    lines = evaluate_arrays(ref, images, noisy=noisy, info=info).format_table().splitlines()
    assert any("kpcn [out.exr]" in line for line in lines)
    assert any("kpcn [out2.exr]" in line for line in lines)
    assert any(" nlm " in line and "[" not in line for line in lines)


def test_empty_result_still_writes_a_valid_report(tmp_path):
    result = EvalResult(metrics=["relmse"], version="0", created="now")
    result.records.append(EvalRecord(scene="s", file="f", metrics={"relmse": None}))
    paths = write_report(result, tmp_path)
    assert load_json(paths["json"])["records"][0]["file"] == "f"
    assert "Scene: s" in paths["html"].read_text(encoding="utf-8")


def test_rewriting_a_report_removes_its_stale_images_only(tmp_path):
    ref, noisy, outputs = scene_images(8, 8)
    big = evaluate_arrays(ref, {"a": outputs["good"], "b": outputs["blurry"]}, noisy=noisy)
    paths = write_report(big, tmp_path)
    mine = paths["images"] / "holiday.png"  # not a name the report writes: kept
    mine.write_bytes(b"x")
    small = evaluate_arrays(ref, {"a": outputs["good"]}, metrics=["relmse"])
    write_report(small, tmp_path)
    parser = _Refs()
    parser.feed(paths["html"].read_text(encoding="utf-8"))
    names = {p.name for p in paths["images"].iterdir()}
    assert names == {Path(r).name for r in parser.refs} | {"holiday.png"}


def test_without_flip_the_column_is_dropped_and_the_reason_kept(tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "flip_evaluator", None)  # as if not installed
    ref, noisy, outputs = scene_images(8, 8)
    result = evaluate_arrays(ref, {"a": outputs["good"]}, noisy=noisy)
    paths = write_report(result, tmp_path / "all")
    page = paths["html"].read_text(encoding="utf-8")
    table = re.search(r'<table class="results">.*?</table>', page).group(0)
    assert "<th>FLIP</th>" not in table and "<th>SSIM</th>" in table
    assert "FLIP not computed for 2 of 2 images: flip_evaluator is not installed" in page
    rec = load_json(paths["json"])["records"][1]
    assert rec["metrics"]["flip"] is None and "not installed" in rec["unavailable"]["flip"]
    only = evaluate_arrays(ref, {"a": outputs["good"]}, metrics=["flip"])
    page = write_report(only, tmp_path / "flip")["html"].read_text(encoding="utf-8")
    table = re.search(r'<table class="results">.*?</table>', page).group(0)
    assert "<th>FLIP</th>" in table and ">n/a</td>" in table


def test_mean_bias_in_every_format(tmp_path):
    """Mean bias (issue 20 item 7): a column in HTML (percent, R G B under it, best = closest
    to 0), the CSV and JSON (fractions, every channel) and the terminal table (summary only)."""
    ref, noisy, _ = scene_images()
    ref = ref + 0.05  # no zero pixels: each channel's mean is well away from 0
    dark = ref * np.float32(0.96)  # 4 % of the energy lost in every channel
    bright = ref.copy()
    bright[0] *= np.float32(1.03)  # 3 % more red only
    result = evaluate_arrays(ref, {"dark": dark, "bright": bright}, noisy=noisy, scene="s")
    by = {r.file: r for r in result.records}
    assert by["dark"].metrics["bias"] == pytest.approx(-0.04, abs=1e-6)
    assert by["bright"].metrics["bias_r"] == pytest.approx(0.03, abs=1e-6)
    assert by["bright"].metrics["bias_g"] == pytest.approx(0.0, abs=1e-6)
    paths = write_report(result, tmp_path)
    page = paths["html"].read_text(encoding="utf-8")
    head = re.search(r'<table class="results"><thead>(.*?)</thead>', page).group(1)
    assert "<th>mean bias</th>" in head and "bias R" not in head  # R, G, B under the summary
    dark_cells = " ".join(_cells(page, "dark"))
    assert "\u22124.00 %" in dark_cells and "R \u22124.00 % G \u22124.00 % B \u22124.00 %" in page
    # bright's +1.x % is closer to 0 than dark's -4 %: it is the bold one, not the most negative
    bias_best = re.findall(r'<b class="best">([+\u2212][0-9.]+ %)</b>', page)
    assert len(bias_best) == 1 and bias_best[0].startswith("+"), bias_best
    assert "closest to 0 is best" in page
    with open(paths["csv"], newline="", encoding="utf-8") as f:
        rows = {r["file"]: r for r in csv.DictReader(f)}
    assert float(rows["dark"]["bias_b"]) == pytest.approx(-0.04, abs=1e-6)
    data = load_json(paths["json"])
    assert data["metrics"]["bias"]["best"] == "closest to 0"
    text = result.format_table()
    assert "-4.00%" in text and "bias R" not in text

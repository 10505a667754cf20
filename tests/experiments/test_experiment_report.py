"""Tests of ``mcdenoise/experiments/report.py`` (and ``plots.py``): the written files of a
synthetic experiment — every image present and not blank, the page offline and complete,
provenance and definitions stated, CSV consistent with JSON, stale images pruned."""

from __future__ import annotations

import csv
import json
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from synthetic_data import FakeMethods, blend, make_render_folder, write_spec

from mcdenoise.experiments import load_experiment, run_experiment
from mcdenoise.experiments.provenance import data_hash


class Page(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.images: list[str] = []
        self.links: list[str] = []
        self.ids: set[str] = set()

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if "id" in a:
            self.ids.add(a["id"])
        if tag == "img":
            self.images.append(a["src"])
        if tag == "a":
            self.links.append(a.get("href", ""))


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("report")
    make_render_folder(tmp / "rendered", scenes=("alpha", "beta", "gamma"), size=(20, 28))
    spec = write_spec(
        tmp / "exp.toml",
        """
name = "report test"
description = "Three synthetic scenes."
methods = ["box", "soft", "gone"]
metrics = ["relmse", "smape", "psnr"]
repetitions = 1
warmup = 0
[scenes]
folder = "rendered"
[stats]
baseline = "soft"
bootstrap = 200
""",
    )
    with pytest.MonkeyPatch.context() as mp:
        fake = FakeMethods(mp)
        fake.add("box", blend)
        fake.add("soft", blend, defaults={"strength": 0.5})
        fake.add("gone", unavailable=lambda: "not installed here")
        out = tmp / "out"
        summary = run_experiment(load_experiment(spec), out)
        (out / "images" / "plot_stale_from_before.png").write_bytes(b"old")
        again = run_experiment(load_experiment(spec), out)  # reuses every unit
        assert again.ran == [] and len(again.reused) == len(summary.ran)
    page = (out / "report.html").read_text(encoding="utf-8")
    parser = Page()
    parser.feed(page)
    return out, page, parser, json.loads((out / "results.json").read_text())


def test_every_image_exists_decodes_and_is_not_blank(report):
    import OpenImageIO as oiio

    out, _, parser, _ = report
    assert len(parser.images) == 3 + 3 * (2 + 3 * 2 + 2)  # plots; per scene plots and strip
    for src in parser.images:
        assert not src.startswith(("http:", "https:", "/")), src  # offline, relative
        path = out / src
        assert path.is_file(), src
        pixels = oiio.ImageBuf(str(path)).get_pixels(oiio.FLOAT)
        assert pixels.size > 0 and float(np.std(pixels)) > 0.01, f"{src} is blank"
    names = {Path(s).name for s in parser.images}
    for plot in ("overall_error_spp", "overall_error_time", "overall_speedup"):
        assert f"plot_{plot}.png" in names
    assert {
        f"plot_{i:02d}_{s}_error_spp.png" for i, s in enumerate(["alpha", "beta", "gamma"])
    } <= names


def test_stale_images_are_pruned(report):
    out, _, _, _ = report
    assert not (out / "images" / "plot_stale_from_before.png").exists()
    shown = {Path(s).name for s in report[2].images}
    assert {p.name for p in (out / "images").glob("*.png")} == shown


def test_page_structure_links_and_sections(report):
    _, page, parser, _ = report
    for anchor in (
        "overall",
        "equal-time",
        "equal-quality",
        "statistics",
        "definitions",
        "provenance",
    ):
        assert anchor in parser.ids
    for href in parser.links:
        assert href.startswith("#") and href[1:] in parser.ids, href
    assert "<script" not in page and "http://" not in page and "https://" not in page
    assert "How to read this report" in page and "Three synthetic scenes." in page
    assert "gone (not installed here)" in page  # the skipped method and why
    assert page.count("Scene: ") == 3


def test_provenance_and_definitions_are_stated(report):
    out, page, _, data = report
    prov = data["provenance"]
    files = [s["noisy_file"] for s in data["scenes"]] + [
        s["reference_file"] for s in data["scenes"]
    ]
    assert prov["data_hash"] == data_hash(out.parent / "rendered", files)
    assert prov["data_hash"] in page and prov["git_commit"] in page
    assert prov["packages"]["numpy"] and prov["packages"]["torch"]
    assert prov["machine"]["torch_threads"] >= 1 and "machine_at_start" in prov
    assert "mean((x − r)² / (r² + ε)), ε = 0.01" in page  # relMSE with its ε
    assert "linear HDR RGB" in page and "sRGB" in page  # colour spaces
    assert data["definitions"]["noise_floor"].startswith("expected relMSE of the reference")
    for s in data["scenes"]:
        assert f"reference noise floor {s['noise_floor']:.2e}" in page
        assert f"seed {s['seed']}" in page
    assert data["statistics"]["baseline"] == "soft" and data["statistics"]["resamples"] == 200


def test_csv_matches_json(report):
    out, _, _, data = report
    with open(out / "results.csv", newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(data["records"]) == 3 * 3 * 3  # scenes x levels x methods
    for row, rec in zip(rows, data["records"]):
        assert (row["scene"], row["method"], int(row["spp"])) == (
            rec["scene"],
            rec["method"],
            rec["spp"],
        )
        assert float(row["relmse"]) == rec["metrics"]["relmse"]
        assert float(row["total_seconds"]) == pytest.approx(rec["total_seconds"])
        if rec["equal_quality"]:
            assert float(row["speedup"]) == pytest.approx(rec["equal_quality"]["speedup"])


def test_overall_tables_and_statistics_are_consistent(report):
    _, page, _, data = report
    rows = {(r["method"], r["spp"]): r for r in data["overall"]["rows"]}
    recs = data["records"]
    for (method, spp), row in rows.items():
        errs = [r["metrics"]["relmse"] for r in recs if r["method"] == method and r["spp"] == spp]
        assert row["complete"] and row["scenes"] == 3
        assert row["relmse"] == pytest.approx(float(np.exp(np.mean(np.log(errs)))))
    for r in data["overall"]["equal_time"]:
        best = r["best"]
        fits = [v for v in rows.values() if v["seconds"] <= r["budget"]]
        assert best["error"] == pytest.approx(min(v["relmse"] for v in fits))
    stat = {(s["method"], s["spp"]): s for s in data["statistics"]["rows"]}
    # box is the full box filter, soft (the baseline) half of it: box has the lower error
    for spp in (1, 2, 4):
        s = stat[("box", spp)]
        assert s["ratio"] < 1 and s["ci_low"] <= s["ratio"] <= s["ci_high"]
        assert s["beats_baseline"] == 3
    assert re.search(r"Equal time: the best choice for a time budget", page)

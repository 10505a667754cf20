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
from synthetic_data import FakeMethods, blend, box3, make_render_folder, write_spec

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
    assert "http://" not in page and "https://" not in page
    # one script, local: the image viewer's (everything else is plain HTML and CSS)
    assert set(re.findall(r"<script\b[^>]*>", page)) == {'<script defer src="viewer/viewer.js">'}
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


# --- issue 20 item 6: headlines agree with the statistics; flagged scenes -------------------


def reassemble(result, records):
    """The findings of ``result`` recomputed from edited unit ``records``."""
    from mcdenoise.experiments.analysis import assemble
    from mcdenoise.experiments.dataset import load_dataset

    return assemble(
        result.spec,
        scenes=load_dataset(result.data_folder, [s.id for s in result.scenes]),
        entries=result.entries,
        skipped=result.skipped,
        records=records,
        metrics=result.metrics,
        data_folder=result.data_folder,
        strip_spp=result.strip_spp,
        out=result.out,
    )


def edited(result, changes):
    """Copies of the unit records with ``{(scene, spp, method): relmse}`` replaced."""
    out = []
    for r in result.records:
        r = json.loads(json.dumps(r))
        key = (r["scene"], r["spp"], r["method"])
        if key in changes:
            r["metrics"]["relmse"] = changes[key]
        out.append(r)
    return out


@pytest.fixture(scope="module")
def small_result(tmp_path_factory):
    """box (3x3 box filter) and soft (half of it, the baseline) on three scenes."""
    tmp = tmp_path_factory.mktemp("headlines")
    make_render_folder(tmp / "rendered", scenes=("alpha", "beta", "gamma"), size=(16, 16))
    spec = write_spec(
        tmp / "exp.toml",
        """
name = "headlines"
methods = ["box", "soft"]
metrics = ["relmse"]
repetitions = 1
warmup = 0
[scenes]
folder = "rendered"
[stats]
baseline = "soft"
bootstrap = 500
[report]
strip_spp = 2
""",
    )
    with pytest.MonkeyPatch.context() as mp:
        fake = FakeMethods(mp)
        fake.add("box", blend)
        fake.add("soft", blend, defaults={"strength": 0.5})
        return run_experiment(load_experiment(spec), tmp / "out").result


def test_headline_names_a_clear_winner_only_when_the_interval_excludes_1(small_result):
    from mcdenoise.experiments.headlines import headlines

    text = " ".join(headlines(small_result))
    # box beats soft in every scene: its ratio interval lies below 1
    row = next(s for s in small_result.stats if s.method == "box" and s.spp == 2)
    assert row.ci_high < 1
    assert "At 2 spp the lowest error is <b>box</b>" in text and "clearly below" in text
    assert "tied within the interval" not in text.split("With the largest budget")[0]


def test_headline_calls_an_interval_containing_1_a_tie_not_a_win(small_result):
    from mcdenoise.experiments.headlines import headlines

    # box lower than soft in two scenes, higher in the third: lower geometric mean, but
    # the bootstrap interval of box / soft contains 1 (the kalantari-nlm vs OIDN)
    changes = {
        ("alpha", 2, "box"): 0.010,
        ("alpha", 2, "soft"): 0.020,
        ("beta", 2, "box"): 0.010,
        ("beta", 2, "soft"): 0.015,
        ("gamma", 2, "box"): 0.030,
        ("gamma", 2, "soft"): 0.012,
    }
    result = reassemble(small_result, edited(small_result, changes))
    row = next(s for s in result.stats if s.method == "box" and s.spp == 2)
    assert row.ratio < 1 and row.ci_low < 1 < row.ci_high and row.verdict == "no clear difference"
    first = headlines(result)[0]
    assert "the lowest error is" not in first and "clearly" not in first
    assert "<b>box</b> has the lowest mean error" in first
    assert "<b>tied within the interval</b> (no clear difference) with soft" in first
    # the numbers quoted are the statistics table's
    assert f"box ÷ soft {row.ratio:.3g}" in first
    assert f"interval {row.ci_low:.3g}\u2013{row.ci_high:.3g}, as in the statistics table" in first
    assert "no single method is lowest at 2 spp" in first


def test_paired_ratio_is_seeded_and_brackets_the_point():
    from mcdenoise.experiments.headlines import paired_ratio

    errors = {("a", 1, "x"): 1.0, ("a", 1, "y"): 2.0, ("b", 1, "x"): 3.0, ("b", 1, "y"): 2.0}
    got = paired_ratio(
        errors, ["a", "b"], ("x", 1), ("y", 1), resamples=300, confidence=0.95, seed=0
    )
    again = paired_ratio(
        errors, ["a", "b"], ("x", 1), ("y", 1), resamples=300, confidence=0.95, seed=0
    )
    assert got == again
    r, lo, hi, n = got
    assert r == pytest.approx(np.sqrt(0.5 * 1.5)) and lo <= r <= hi and n == 2
    assert lo < 1 < hi  # one scene each way: no clear difference
    assert (
        paired_ratio(errors, ["c"], ("x", 1), ("y", 1), resamples=10, confidence=0.9, seed=0)
        is None
    )


def test_rising_noisy_curve_flags_the_scene_and_the_report_offers_it_excluded(
    small_result, tmp_path, monkeypatch
):
    from mcdenoise.experiments.report import write_experiment_report

    noisy = {s: small_result.record(s, 1, "noisy")["metrics"]["relmse"] for s in ("beta",)}
    # beta's noisy error rises from 1 to 2 spp (a firefly at 2 spp)
    result = reassemble(
        small_result, edited(small_result, {("beta", 2, "noisy"): noisy["beta"] * 3})
    )
    assert result.flagged == ["beta"]
    beta = next(s for s in result.scenes if s.id == "beta")
    assert beta.rises and beta.rises[0][0] == 1 and beta.rises[0][2] == 2
    assert "rises with more samples" in beta.flag_reason and "fireflies" in beta.flag_reason
    view = result.without_flagged
    assert view is not None and view.scenes == ["alpha", "gamma"]
    # the rows without beta are the geometric means over alpha and gamma only
    row = next(o for o in view.rows if o.method == "box" and o.spp == 4)
    errs = [result.record(s, 4, "box")["metrics"]["relmse"] for s in ("alpha", "gamma")]
    assert row.relmse == pytest.approx(float(np.exp(np.mean(np.log(errs)))))
    assert all(s.scenes == 2 for s in view.stats)

    fake = FakeMethods(monkeypatch)  # the report describes the methods' parameters
    fake.add("box", blend)
    fake.add("soft", blend, defaults={"strength": 0.5})
    paths = write_experiment_report(result, tmp_path)
    page = paths["html"].read_text(encoding="utf-8")
    data = json.loads(paths["json"].read_text(encoding="utf-8"))
    assert data["flagged_scenes"] == ["beta"]
    assert data["overall_without_flagged"]["scenes"] == ["alpha", "gamma"]
    assert next(s for s in data["scenes"] if s["id"] == "beta")["flagged"] is True
    # the scene's section says why; the headlines name it
    assert "<b>Flagged.</b> The error (relMSE) of plain rendering rises" in page
    assert "Flagged: the noisy error rises with more samples" in page
    # both versions of every over-all-scenes section, the switch with no script
    assert "<script" not in page[: page.index('class="mcdv"')]
    assert page.count('<div class="v-all">') == page.count('<div class="v-unflagged">') == 4
    assert "images/plot_unflagged_error_spp.png" in page
    assert (tmp_path / "images" / "plot_unflagged_error_time.png").is_file()
    radios = page.index('id="scope-unflagged"')
    assert radios < page.index('<div class="v-all">') and radios < page.index('id="overall"')
    # the radio inputs and the versions are siblings in <body> (CSS ``~`` needs that)
    body = page[page.index("<body>") : page.index("</body>")]
    before = body[: body.index('id="scope-all"')]
    assert before.count("<div") == before.count("</div>")  # not inside an open element
    css = paths["html"].read_text(encoding="utf-8").split("</style>")[0]
    assert "#scope-unflagged:checked ~ .v-unflagged" in css
    assert "#scope-unflagged:checked ~ .v-all" in css


def test_bias_column_table_and_headline(tmp_path):
    # little noise: the inputs' means stay well within 2 % of the references'
    make_render_folder(tmp_path / "rendered", scenes=("alpha", "beta"), size=(16, 16), sigma=0.05)
    spec = write_spec(
        tmp_path / "exp.toml",
        """
name = "bias"
methods = ["box", "dim"]
metrics = ["relmse", "bias"]
repetitions = 1
warmup = 0
[scenes]
folder = "rendered"
[stats]
baseline = "box"
bootstrap = 100
""",
    )

    def dim(b, p, d):
        return 0.95 * box3(b["color"])  # 5 % of the energy lost

    with pytest.MonkeyPatch.context() as mp:
        fake = FakeMethods(mp)
        fake.add("box", blend)
        fake.add("dim", dim)
        result = run_experiment(load_experiment(spec), tmp_path / "out").result
    out = tmp_path / "out"
    rec = result.record("alpha", 4, "dim")
    assert rec["metrics"]["bias"] == pytest.approx(-0.05, abs=0.01)
    assert set(rec["metrics"]) >= {"bias", "bias_r", "bias_g", "bias_b"}
    with open(out / "results.csv", newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    assert {"bias", "bias_r", "bias_g", "bias_b"} <= set(rows[0])
    data = json.loads((out / "results.json").read_text(encoding="utf-8"))
    row = next(o for o in data["overall"]["rows"] if o["method"] == "dim" and o["spp"] == 4)
    assert row["bias"] == pytest.approx(-0.05, abs=0.01) and row["bias_min"] <= row["bias"]
    page = (out / "report.html").read_text(encoding="utf-8")
    assert "Mean bias over scenes" in page
    headline = re.search(r"Mean bias beyond ±2%.*?</li>", page).group(0)
    assert "<b>dim</b>" in headline and "<b>box</b>" not in headline
    assert "the noisy input there" in headline


def test_log_ticks_label_every_decade_and_short_ranges():
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from mcdenoise.experiments.plots import log_ticks

    def labels(lo, hi, base=10):
        fig = Figure()
        FigureCanvasAgg(fig)
        ax = fig.add_subplot()
        ax.set_xscale("log", base=base)
        ax.set_xlim(lo, hi)
        log_ticks(ax.xaxis, lo, hi, base=base)
        fig.canvas.draw()
        major = [t.label1.get_text() for t in ax.xaxis.get_major_ticks() if lo <= t.get_loc() <= hi]
        minor = [t.label1.get_text() for t in ax.xaxis.get_minor_ticks() if lo <= t.get_loc() <= hi]
        return major, [m for m in minor if m]

    major, minor = labels(1e-4, 1e2)  # six decades: every decade labelled, minors not
    assert major == ["0.0001", "0.001", "0.01", "0.1", "1", "10", "100"] and minor == []
    major, minor = labels(0.04, 1.2)  # the time axis: one decade -> minors too
    assert major == ["0.1", "1"] and minor == ["0.05", "0.2", "0.5"]
    major, _ = labels(1, 64, base=2)
    assert major == ["1", "2", "4", "8", "16", "32", "64"]

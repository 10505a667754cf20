"""A tiny real experiment end to end: two scene specs rendered by Mitsuba (32×32, 1–4 spp,
``scalar_rgb``), two registry methods, the report's numbers recomputed from the written EXRs,
and a second run that renders and denoises nothing."""

from __future__ import annotations

import json

import pytest
from synthetic_data import write_spec

from mcdenoise.eval.metrics import compute_metrics
from mcdenoise.experiments import load_experiment, run_experiment
from mcdenoise.io import load_buffers
from mcdenoise.render.manifest import load_manifest

pytestmark = pytest.mark.mitsuba

BALL = """
name = "{name}"
effects = ["direct"]
[camera]
origin = [0, 1, 4]
target = [0, 0.5, 0]
[[objects]]
shape = "rectangle"
transform = {{ rotate = [-90, 0, 0], scale = [3, 3, 1] }}
[objects.material]
type = "diffuse"
[objects.material.reflectance.checkerboard]
color0 = [0.2, 0.2, 0.2]
color1 = [0.8, 0.8, 0.8]
scale = 4
[[objects]]
shape = "sphere"
center = [0, 0.5, 0]
radius = {radius}
material = {{ type = "diffuse", reflectance = [0.7, 0.3, 0.2] }}
[[lights]]
type = "point"
position = [1, 3, 2]
intensity = [20, 20, 20]
[[lights]]
type = "constant"
radiance = [0.2, 0.2, 0.25]
"""

EXPERIMENT = """
name = "tiny"
methods = ["xbf", "nlm"]
metrics = ["relmse", "smape", "psnr", "ssim"]
repetitions = 1
warmup = 0
[scenes]
specs = ["scenes"]
[render]
resolution = 32
spp = [1, 2, 4]
ref_spp = 32
variant = "scalar_rgb"
seed = 3
[report]
strip_spp = 4
"""


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tiny")
    for name, radius in (("small_ball", 0.3), ("big_ball", 0.6)):
        write_spec(tmp / "scenes" / f"{name}.toml", BALL.format(name=name, radius=radius))
    spec = load_experiment(write_spec(tmp / "tiny.toml", EXPERIMENT))
    out = tmp / "out"
    first = run_experiment(spec, out)
    return spec, out, first


def test_renders_into_the_data_folder_and_runs_every_unit(tiny):
    _, out, first = tiny
    assert sorted(first.rendered) == ["big_ball", "small_ball"] and first.render_skipped == []
    assert len(first.ran) == 2 * 3 * 3
    manifest = load_manifest(out / "data")
    assert manifest["settings"]["spp"] == [1, 2, 4] and manifest["variants"] == ["scalar_rgb"]
    data = json.loads((out / "results.json").read_text())
    seconds = {
        (img["id"], lv["spp"]): lv["render_seconds"]
        - sum(x.get("jit_seconds", 0.0) for x in img["levels"] if x["spp"] <= lv["spp"])
        for img in manifest["images"]
        for lv in img["levels"]
    }
    for r in data["records"]:
        assert r["render_seconds"] == pytest.approx(seconds[(r["scene"], r["spp"])])
    assert {m["label"] for m in data["methods"]} == {"noisy", "xbf", "nlm"}


def test_report_numbers_match_metrics_recomputed_from_the_exrs(tiny):
    _, out, _ = tiny
    data = json.loads((out / "results.json").read_text())
    names = ["relmse", "smape", "psnr", "ssim"]
    for r in data["records"]:
        ref = load_buffers(out / "data" / "ref" / f"{r['scene']}.exr")["color"]
        if r["method"] == "noisy":
            image = load_buffers(out / "data" / f"{r['scene']}.exr", part=f"spp{r['spp']}")["color"]
        else:
            image = load_buffers(out / r["output"])["color"]
        again = compute_metrics(image, ref, names).values
        for m in names:
            assert r["metrics"][m] == pytest.approx(again[m], rel=1e-12, abs=0), (r["method"], m)
    page = (out / "report.html").read_text()
    assert "big_ball" in page and "small_ball" in page


def test_second_run_renders_and_denoises_nothing(tiny):
    spec, out, first = tiny
    before = (out / "results.json").read_text()
    again = run_experiment(spec, out)
    assert again.rendered == [] and sorted(again.render_skipped) == ["big_ball", "small_ball"]
    assert again.ran == [] and sorted(again.reused) == sorted(first.ran)
    after = json.loads((out / "results.json").read_text())
    assert [r["metrics"] for r in after["records"]] == [
        r["metrics"] for r in json.loads(before)["records"]
    ]

"""Experiments on data without our manifests (issue 26 item 4): a folder of plain Mitsuba
``aov`` files and references is a scene source; render time is unknown (``null``, never 0),
totals, Pareto fronts, equal-time tables and speed-ups are left out and the report says so;
the errors are those ``mcdenoise eval`` computes on the same files."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from mcdenoise_cli.main import main
from synthetic_data import blend, clean_image, write_spec

from mcdenoise.eval.metrics import compute_metrics
from mcdenoise.experiments import ExperimentError
from mcdenoise.experiments.definitions import RENDER_TIME_UNKNOWN
from mcdenoise.experiments.folder_data import scan_folder
from mcdenoise.io import load_buffers
from mcdenoise.io.exr_write import write_exr

MITSUBA = {"generatedBy": "Mitsuba version 3.9.1"}


def mitsuba_aov(path: Path, color: np.ndarray, *, features: bool = True) -> None:
    """A file as Mitsuba's ``aov`` integrator writes it: R,G,B, albedo.*, nn.* (no spp)."""
    h, w = color.shape[1:]
    channels = {"R": color[0], "G": color[1], "B": color[2]}
    if features:
        channels |= {f"albedo.{c}": np.full((h, w), 0.7, np.float32) for c in "RGB"}
        channels |= {"nn.X": np.zeros((h, w)), "nn.Y": np.zeros((h, w)), "nn.Z": np.ones((h, w))}
    write_exr(path, channels, attributes=MITSUBA)


def make_mitsuba_folder(folder: Path, scenes=("attic", "barn"), spp=(2, 8)) -> Path:
    rng = np.random.default_rng(5)
    (folder / "ref").mkdir(parents=True)
    for k, name in enumerate(scenes):
        clean = clean_image(12, 16, phase=k)
        for n in spp:
            noisy = clean + rng.normal(0, 0.3 / np.sqrt(n), clean.shape)
            mitsuba_aov(folder / f"{name}_spp{n}.exr", noisy.astype(np.float32))
        mitsuba_aov(folder / "ref" / f"{name}.exr", clean.astype(np.float32), features=False)
    return folder


SPEC = """
name = "plain-files"
methods = ["box"]
metrics = ["relmse", "psnr"]
repetitions = 1
warmup = 0
[scenes]
folder = "aov"
"""


@pytest.fixture(scope="module")
def plain_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("plain")
    make_mitsuba_folder(tmp / "aov")
    spec = write_spec(tmp / "exp.toml", SPEC)
    with pytest.MonkeyPatch.context() as mp:
        from synthetic_data import FakeMethods

        FakeMethods(mp).add("box", blend)
        result = CliRunner().invoke(
            main, ["eval", "--experiment", str(spec), "-o", str(tmp / "out")]
        )
    return tmp, result


def test_a_folder_of_mitsuba_files_and_references_is_an_experiment(plain_run):
    tmp, result = plain_run
    assert result.exit_code == 0, result.output + result.stderr
    assert "2 scene(s) x 2 spp level(s) x 2 method(s)" in result.output
    data = json.loads((tmp / "out" / "results.json").read_text())
    assert [s["id"] for s in data["scenes"]] == ["attic", "barn"]
    for r in data["records"]:
        assert r["render_seconds"] is None and r["total_seconds"] is None
        if r["method"] == "box":
            assert r["denoise_seconds"] > 0  # what is known is kept
            assert r["equal_quality"]["spp"] > 0 and r["equal_quality"]["speedup"] is None
            assert r["input"]["file"].endswith(f"{r['scene']}_spp{r['spp']}.exr")
    assert data["overall"]["pareto"] == [] and data["overall"]["equal_time"] == []
    assert all(row["seconds"] is None for row in data["overall"]["rows"])
    assert RENDER_TIME_UNKNOWN in data["notes"]
    html = (tmp / "out" / "report.html").read_text(encoding="utf-8")
    assert "render time unknown" in html
    assert not list((tmp / "out" / "images").glob("plot_*_error_time.png"))


def test_errors_are_those_of_the_files(plain_run):
    tmp, _ = plain_run
    with open(tmp / "out" / "results.csv", newline="", encoding="utf-8") as f:
        rows = {(r["scene"], r["spp"], r["method"]): r for r in csv.DictReader(f)}
    assert rows[("barn", "8", "noisy")]["render_seconds"] == ""
    noisy = load_buffers(tmp / "aov" / "barn_spp8.exr")["color"].numpy()
    ref = load_buffers(tmp / "aov" / "ref" / "barn.exr")["color"].numpy()
    want = compute_metrics(noisy, ref, ["relmse"]).values["relmse"]
    assert float(rows[("barn", "8", "noisy")]["relmse"]) == pytest.approx(want, rel=1e-6)


def test_scan_refuses_with_one_line(tmp_path):
    folder = make_mitsuba_folder(tmp_path / "a")
    mitsuba_aov(folder / "attic_x.exr", np.ones((3, 12, 16), np.float32))
    with pytest.raises(ExperimentError, match=r"attic_x.exr: its spp is unknown"):
        scan_folder(folder)
    (folder / "attic_x.exr").unlink()
    mitsuba_aov(folder / "silo_spp2.exr", np.ones((3, 12, 16), np.float32))
    with pytest.raises(ExperimentError, match=r"no reference in .* whose name begins"):
        scan_folder(folder)
    (folder / "silo_spp2.exr").unlink()
    (folder / "barn_spp8.exr").unlink()
    with pytest.raises(ExperimentError, match=r"different spp levels .* \(2\)"):
        scan_folder(folder)
    assert [lv.spp for lv in scan_folder(folder, spp=[2])[0].levels] == [2]
    with pytest.raises(ExperimentError, match="has no level"):
        scan_folder(folder, spp=[8])


def test_references_elsewhere_and_content_fingerprints(tmp_path):
    folder = make_mitsuba_folder(tmp_path / "a")
    (folder / "ref").rename(tmp_path / "refs")
    scenes = scan_folder(folder, references=tmp_path / "refs")
    assert [s.reference.parent.name for s in scenes] == ["refs", "refs"]
    before = scenes[0].fingerprint
    mitsuba_aov(folder / "attic_spp2.exr", np.ones((3, 12, 16), np.float32))
    assert scan_folder(folder, references=tmp_path / "refs")[0].fingerprint != before


def test_the_references_key_is_checked(tmp_path):
    from mcdenoise.experiments.spec import parse_experiment

    make_mitsuba_folder(tmp_path / "aov")
    spec = parse_experiment(
        {"scenes": {"folder": "aov", "references": "aov/ref"}}, source="s.toml", base=tmp_path
    )
    assert spec.references == (tmp_path / "aov" / "ref").resolve()
    assert spec.to_dict()["scenes"]["references"] == str(spec.references)
    with pytest.raises(ExperimentError, match=r"s\.toml: scenes\.references: 'nope' is not a"):
        parse_experiment(
            {"scenes": {"folder": "aov", "references": "nope"}}, source="s.toml", base=tmp_path
        )
    with pytest.raises(ExperimentError, match=r"goes with scenes\.folder"):
        parse_experiment({"scenes": {"random": 1, "references": "aov"}}, source="s.toml")

"""An OIDN-style data set is judged here (issue 26 item 3): a render folder written in OIDN's
training layout (``write_oidn_layout``) is a ``[scenes] folder`` of an experiment; its levels,
features and references are those of the render folder, so the errors are the same."""

from __future__ import annotations

import json

import pytest
import torch
from synthetic_data import FakeMethods, make_render_folder, write_spec

from mcdenoise.eval.metrics import compute_metrics
from mcdenoise.experiments import load_experiment, run_experiment
from mcdenoise.experiments.dataset import load_dataset, read_level
from mcdenoise.io import load_buffers
from mcdenoise.io.oidn_layout import write_oidn_layout

SPEC = """
name = "oidn-set"
methods = ["albedo-mean"]
metrics = ["relmse"]
repetitions = 1
warmup = 0
[scenes]
folder = "oidn"
"""


def albedo_mean(b, p, d):
    """Needs the albedo (from the .alb.exr files): the colour scaled by the albedo's mean."""
    return b["color"] * (b["albedo"].mean() / 0.7)


@pytest.fixture(scope="module")
def oidn_set(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("oidn")
    render = make_render_folder(tmp / "render", scenes=("alpha", "beta"), size=(12, 16))
    write_oidn_layout(render, tmp / "oidn")
    return tmp, render


def test_the_oidn_set_reads_as_the_render_folder(oidn_set):
    tmp, render = oidn_set
    ours, theirs = load_dataset(render), load_dataset(tmp / "oidn")
    assert [s.id for s in theirs] == [s.id for s in ours]
    for a, b in zip(ours, theirs, strict=True):
        assert [lv.spp for lv in b.levels] == [lv.spp for lv in a.levels]
        assert all(lv.render_seconds is None for lv in b.levels)
        assert b.reference.name == f"{a.id}_ref.hdr.exr"
        for la, lb in zip(a.levels, b.levels, strict=True):
            x, y = read_level(a.noisy, la), read_level(b.noisy, lb)
            assert y.spp == la.spp
            for name in ("color", "albedo", "normal"):
                assert torch.equal(x[name], y[name]), name


def test_an_experiment_on_the_oidn_set_measures_the_same_errors(oidn_set):
    tmp, render = oidn_set
    with pytest.MonkeyPatch.context() as mp:
        FakeMethods(mp).add("albedo-mean", albedo_mean, requires=("color", "albedo"))
        mp.setattr("mcdenoise.experiments.plots.plots_unavailable", lambda: "not drawn here")
        spec = load_experiment(write_spec(tmp / "exp.toml", SPEC))
        run_experiment(spec, tmp / "out")
    data = json.loads((tmp / "out" / "results.json").read_text())
    assert not [r for r in data["records"] if r.get("error")]
    for r in data["records"]:
        if r["method"] != "noisy":
            continue
        noisy = load_buffers(render / f"{r['scene']}.exr", part=f"spp{r['spp']}")
        ref = load_buffers(render / "ref" / f"{r['scene']}.exr")
        want = compute_metrics(noisy["color"].numpy(), ref["color"].numpy(), ["relmse"])
        assert r["metrics"]["relmse"] == pytest.approx(want.values["relmse"], rel=1e-6)
        assert r["input"]["file"].endswith(f"{r['scene']}_{r['spp']:04d}spp.hdr.exr")

"""Sequence experiments (issue 23 item 5) on a synthetic folder of sequences: 32×32, 4 frames,
a per-frame box filter and a temporal running mean; end to end, resume, and the spec."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from synthetic_data import write_spec
from synthetic_sequences import add_running_mean, make_sequence_folder

from mcdenoise.eval.temporal_metrics import sequence_metrics
from mcdenoise.experiments import ExperimentError, load_experiment, run_experiment
from mcdenoise.io import load_buffers

SPEC = """
name = "seq"
methods = ["box", "running-mean"]
repetitions = 2
warmup = 0
threads = 1
[scenes]
folder = "{folder}"
[stats]
bootstrap = 100
[report]
strip_spp = 2
warmup_frames = 1
"""


@pytest.fixture
def seq_experiment(tmp_path, fake_methods, monkeypatch):
    folder = make_sequence_folder(tmp_path / "render", scenes=("walk", "drift"), frames=4)
    fake_methods.add("box")
    add_running_mean(monkeypatch, fake_methods.calls)
    spec = load_experiment(write_spec(tmp_path / "seq.toml", SPEC.format(folder=folder.as_posix())))
    return spec, folder, fake_methods.calls


def test_sequence_experiment_end_to_end(seq_experiment, tmp_path):
    spec, folder, calls = seq_experiment
    out = tmp_path / "out"
    summary = run_experiment(spec, out)
    # 2 sequences x 2 levels x (noisy, box, running-mean)
    assert len(summary.ran) == 12 and not summary.reused
    # the temporal method saw every sequence whole, once per timed run (2 repetitions)
    assert calls["running-mean"] == 2 * 2 * 2
    # the per-frame method ran on each of the 4 frames of every run
    assert calls["box"] == 2 * 2 * 2 * 4

    data = json.loads((out / "results.json").read_text())
    assert data["temporal"]["warmup_frames"] == 1
    rows = {(r["method"], r["spp"]): r for r in data["temporal"]["rows"]}
    assert rows[("running-mean", 2)]["complete"]
    # averaging along the motion halves the frame-to-frame noise: lower temporal error than
    # the noisy input's
    assert rows[("running-mean", 2)]["trelmse"] < rows[("noisy", 2)]["trelmse"]

    rec = next(
        r
        for r in data["records"]
        if r["scene"] == "walk" and r["spp"] == 2 and r["method"] == "running-mean"
    )
    assert rec["frames_count"] == 4 and len(rec["frames"]) == 4
    assert [f["warmup"] for f in rec["frames"]] == [True, False, False, False]
    # per-frame times: the unit's time is the mean over frames, the total adds render/frame
    assert rec["total_seconds"] == pytest.approx(rec["render_seconds"] + rec["denoise_seconds"])
    # render seconds per frame: 2 spp x 0.01 s, JIT (0.25 s per frame) excluded
    assert rec["render_seconds"] == pytest.approx(0.02)
    # the metrics are eval's sequence_metrics of the written output frames
    outs = [
        load_buffers(out / rec["output"] / f"frame_{t:04d}.exr")["color"].numpy() for t in range(4)
    ]
    refs = [
        load_buffers(folder / "walk" / "ref" / f"frame_{t:04d}.exr")["color"].numpy()
        for t in range(4)
    ]
    expect = sequence_metrics(outs, refs, ["relmse", "trelmse", "tpsnr"], warmup=1)
    for m in ("relmse", "trelmse", "tpsnr"):
        assert rec["metrics"][m] == pytest.approx(expect.values[m], rel=1e-6)
    assert rec["warmup_metrics"]["relmse"] == pytest.approx(expect.warmup_values["relmse"])

    # results.csv has the temporal columns, frames.csv one row per frame
    with (out / "results.csv").open() as f:
        table = list(csv.DictReader(f))
    assert {"trelmse", "tpsnr", "trmae", "frames", "relmse_warmup"} <= set(table[0])
    row = next(r for r in table if r["method"] == "running-mean" and r["scene"] == "walk")
    assert float(row["trelmse"]) == pytest.approx(rec["metrics"]["trelmse"])
    with (out / "frames.csv").open() as f:
        frames = list(csv.DictReader(f))
    assert len(frames) == 12 * 4

    # the report: x-t slices for noisy, every method and the reference, and an animation
    page = (out / "report.html").read_text()
    assert 'id="sequences"' in page and "temporal relMSE" in page
    images = out / "images"
    for label in ("noisy", "box", "running-mean", "reference"):
        hits = list(images.glob(f"strip_*_walk_xt_*_{label}.png"))
        assert len(hits) == 1, label
        assert f"images/{hits[0].name}" in page
    slice_img = load_png(next(images.glob("strip_*_walk_xt_*_noisy.png")))
    assert slice_img.shape[0] % 4 == 0 and slice_img.shape[0] >= 4 * 2  # 4 frames, rows each
    anims = sorted(images.glob("strip_*_walk_anim.*"))
    assert len(anims) == 1 and f"images/{anims[0].name}" in page
    assert animation_frames(anims[0]) == 4
    assert (images / "plot_sequences_temporal_time.png").is_file()


def test_sequence_experiment_resume(seq_experiment, tmp_path):
    spec, _, calls = seq_experiment
    out = tmp_path / "out"
    run_experiment(spec, out)
    before = dict(calls)
    again = run_experiment(spec, out)
    assert not again.ran and len(again.reused) == 12
    assert calls == before  # nothing was denoised again
    # a lost output frame makes its unit run again, and only that one
    rec = json.loads((out / "results.json").read_text())["records"]
    victim = next(r for r in rec if r["method"] == "running-mean" and r["output"])
    (out / victim["output"] / "frame_0002.exr").unlink()
    third = run_experiment(spec, out)
    assert third.ran == [(victim["scene"], victim["spp"], "running-mean")]


def test_sequence_unit_refused(tmp_path, fake_methods, monkeypatch):
    """A method that refuses a sequence gives a 'could not run' unit, the rest carry on."""
    from synthetic_data import refuse

    folder = make_sequence_folder(tmp_path / "render", frames=3, spp=(2,))
    fake_methods.add("box")
    fake_methods.add("nope", refuse)
    text = SPEC.replace('["box", "running-mean"]', '["box", "nope"]')
    spec = load_experiment(write_spec(tmp_path / "s.toml", text.format(folder=folder.as_posix())))
    run_experiment(spec, tmp_path / "out")
    data = json.loads((tmp_path / "out" / "results.json").read_text())
    nope = next(r for r in data["records"] if r["method"] == "nope")
    assert nope["failed"] and "refuses" in nope["error"]
    page = (tmp_path / "out" / "report.html").read_text()
    assert "refuses" in page


def test_temporal_metrics_need_sequences(tmp_path):
    from synthetic_data import make_render_folder

    stills = make_render_folder(tmp_path / "stills")
    text = f'metrics = ["relmse", "trelmse"]\n[scenes]\nfolder = "{stills.as_posix()}"\n'
    with pytest.raises(ExperimentError, match="temporal metric"):
        load_experiment(write_spec(tmp_path / "a.toml", text))


def test_spec_frames_and_animate(tmp_path):
    from mcdenoise.experiments.dataset import render_jobs

    scene = Path(__file__).resolve().parents[2] / "data" / "scenes" / "cornell.toml"
    specs = f'[scenes]\nspecs = ["{scene.as_posix()}"]\n'
    spec = load_experiment(
        write_spec(
            tmp_path / "ok.toml",
            specs
            + '[scenes.animate.cornell]\nanimation = { camera_path = "orbit", angle = 6 }\n'
            + "move = [{ object = 5, translate = [0.2, 0, 0] }]\n"
            + "[render]\nframes = 3\nspp = [1, 2]\nref_spp = 8\n",
        )
    )
    assert spec.frames == 3 and spec.metrics is None
    assert spec.to_dict()["render"]["frames"] == 3
    (job,) = render_jobs(spec)
    assert job.spec.animation is not None and job.spec.animation.angle == 6
    assert job.spec.objects[5].motion is not None
    bad = [
        (specs + "[render]\nframes = 1\n", "render.frames"),
        (
            specs + "[scenes.animate.nothere]\nanimation = { angle = 3 }\n[render]\nframes = 3\n",
            "nothere",
        ),
        (specs + "[scenes.animate.cornell]\nanimation = { angle = 3 }\n", "only for sequences"),
        ('metrics = ["relmse"]\n' + specs + "[render]\nframes = 3\n", "trelmse"),
    ]
    for i, (text, match) in enumerate(bad):
        with pytest.raises(ExperimentError, match=match):
            load_experiment(write_spec(tmp_path / f"bad{i}.toml", text))
    # an object index past the scene's objects is named when the jobs are made
    spec = load_experiment(
        write_spec(
            tmp_path / "far.toml",
            specs + "[scenes.animate.cornell]\nmove = [{ object = 99, translate = [1, 0, 0] }]\n"
            "[render]\nframes = 3\nspp = [1]\nref_spp = 8\n",
        )
    )
    with pytest.raises(ExperimentError, match="object: cornell has"):
        render_jobs(spec)


def load_png(path: Path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(path))


def animation_frames(path: Path) -> int:
    from PIL import Image

    return int(getattr(Image.open(path), "n_frames", 1))


def test_still_experiment_unchanged(tmp_path, fake_methods):
    """A still experiment writes no sequence column, table or file."""
    from synthetic_data import make_render_folder

    from mcdenoise.experiments.report_tables import CSV_HEAD, CSV_TAIL

    folder = make_render_folder(tmp_path / "stills", scenes=("alpha",), spp=(1, 2))
    fake_methods.add("box")
    text = SPEC.replace('["box", "running-mean"]', '["box"]').replace("warmup_frames = 1\n", "")
    spec = load_experiment(write_spec(tmp_path / "s.toml", text.format(folder=folder.as_posix())))
    assert spec.frames is None and "frames" not in spec.to_dict()["render"]
    out = tmp_path / "out"
    run_experiment(spec, out)
    data = json.loads((out / "results.json").read_text())
    assert "temporal" not in data and not (out / "frames.csv").exists()
    with (out / "results.csv").open() as f:
        header = next(csv.reader(f))
    assert header == [*CSV_HEAD, *data["metrics"], *CSV_TAIL]
    assert not any(m in header for m in ("trelmse", "tpsnr", "trmae", "relmse_warmup"))
    assert not any("frames" in r for r in data["records"])
    assert list((out / "outputs").glob("*.exr"))  # outputs are files, not folders of frames


def test_animation_gif_without_pillow(tmp_path, monkeypatch):
    """Without Pillow the animated strip is a GIF (OpenImageIO), one subimage per frame."""
    import OpenImageIO as oiio

    from mcdenoise.experiments import temporal_report

    monkeypatch.setattr(temporal_report, "animation_writer", lambda: "gif")
    frames = [np.full((6, 10, 3), 30 * t, np.uint8) for t in range(5)]
    path = temporal_report.write_animation(tmp_path / "a", frames, fps=4)
    assert path.suffix == ".gif"
    inp = oiio.ImageInput.open(str(path))
    count = 0
    while inp.seek_subimage(count, 0):
        count += 1
    inp.close()
    assert count == 5


def test_load_sequences(tmp_path):
    """Sequences are read with their frames and per-frame render seconds; an unfinished
    sequence, or a still folder where sequences are expected, is refused in one line."""
    from synthetic_data import make_render_folder

    from mcdenoise.experiments.dataset import load_dataset

    folder = make_sequence_folder(tmp_path / "seq", frames=3, spp=(2, 8))
    (scene,) = load_dataset(folder, sequences=True)
    assert scene.is_sequence and len(scene.frames) == 3
    assert [lv.spp for lv in scene.levels] == [2, 8]
    assert scene.level(8).render_seconds == pytest.approx(0.08)  # JIT excluded per frame
    assert len(scene.files()) == 6
    with pytest.raises(ExperimentError, match="holds sequences"):
        load_dataset(folder)
    manifest = folder / "manifest.json"
    data = json.loads(manifest.read_text())
    data["images"][0]["complete"] = False
    manifest.write_text(json.dumps(data))
    with pytest.raises(ExperimentError, match="frames finished"):
        load_dataset(folder, sequences=True)
    stills = make_render_folder(tmp_path / "stills", scenes=("a",), spp=(1,))
    with pytest.raises(ExperimentError, match="not sequences"):
        load_dataset(stills, sequences=True)

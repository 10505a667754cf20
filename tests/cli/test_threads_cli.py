"""``--threads N|auto`` on every command that computes: accepted, applied and recorded."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
from click.testing import CliRunner
from mcdenoise_cli.main import main

from mcdenoise import threads
from mcdenoise.io import load_buffers
from mcdenoise.registry import get_method

SAMPLE = Path(__file__).resolve().parents[2] / "data" / "samples" / "cornell_spp4.exr"
TINY = ["-s", "kernel=5", "-s", "patch=16", "-s", "margin=2", "-s", "batch=2"]


@pytest.fixture(autouse=True)
def _restore_threads():
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


def run(*args: str):
    return CliRunner().invoke(main, list(args))


def test_denoise_records_the_threads_and_wait_policy_in_the_header(tmp_path: Path) -> None:
    out = tmp_path / "out.exr"
    r = run("denoise", str(SAMPLE), "-o", str(out), "--method", "kpcn", "--threads", "1")
    assert r.exit_code == 0, r.output + r.stderr
    attrs = load_buffers(out).attributes
    assert attrs["mcdenoise:threads"] == 1
    assert attrs["mcdenoise:omp_wait_policy"] == threads.wait_policy()  # as the process runs
    assert torch.get_num_threads() == 1


def test_denoise_auto_is_the_default_and_never_more_than_the_cores(tmp_path: Path) -> None:
    import os

    out = tmp_path / "out.exr"
    r = run("denoise", str(SAMPLE), "-o", str(out), "--method", "kpcn", "--threads", "auto")
    assert r.exit_code == 0, r.output + r.stderr
    used = load_buffers(out).attributes["mcdenoise:threads"]
    assert 1 <= used <= (os.cpu_count() or 1)


@pytest.mark.parametrize("bad", ["0", "-1", "two", "1.5"])
@pytest.mark.parametrize("command", ["denoise", "eval", "train", "render"])
def test_a_bad_thread_count_is_a_usage_error(command: str, bad: str, tmp_path: Path) -> None:
    r = run(command, "--threads", bad, str(SAMPLE))
    assert r.exit_code == 2
    assert "--threads" in r.stderr and "Traceback" not in r.output + r.stderr


@pytest.mark.parametrize("command", ["denoise", "eval", "train", "render"])
def test_every_computing_command_documents_threads(command: str) -> None:
    r = run(command, "--help")
    assert r.exit_code == 0 and "--threads N|auto" in r.output


def test_eval_accepts_threads(tmp_path: Path) -> None:
    out = tmp_path / "cornell_spp4_kpcn.exr"
    assert run("denoise", str(SAMPLE), "-o", str(out), "--method", "kpcn").exit_code == 0
    ref = SAMPLE.parent / "ref" / "cornell.exr"
    r = run("eval", "--threads", "1", "--ref", str(ref), str(out), "-o", str(tmp_path / "rep"))
    assert r.exit_code == 0, r.output + r.stderr
    assert torch.get_num_threads() == 1


EXPERIMENT = """
name = "threads"
methods = ["cross-bilateral"]
threads = 2
[scenes]
folder = "data"
"""


def test_eval_experiment_threads_flag_overrides_the_spec(monkeypatch, tmp_path: Path) -> None:
    seen = []

    def fake_run_experiment(spec, out_dir, **kwargs):
        seen.append(spec.threads)  # the runner times every method with spec.threads
        return SimpleNamespace(messages=lambda: [])

    monkeypatch.setattr("mcdenoise.experiments.run_experiment", fake_run_experiment)
    spec = tmp_path / "threads.toml"
    spec.write_text(EXPERIMENT, encoding="utf-8")
    (tmp_path / "data").mkdir()  # the spec's scene folder (the fake runner reads nothing)
    out = str(tmp_path / "out")
    assert run("eval", "--experiment", str(spec), "-o", out, "--threads", "1").exit_code == 0
    assert run("eval", "--experiment", str(spec), "-o", out).exit_code == 0
    assert seen == [1, 2]  # an explicit flag wins; else the spec's own value


def test_train_threads_flag_is_the_configs_threads(tiny_dataset: Path, tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    r = run(
        "train",
        "--model",
        "kalantari-xbf",
        "--data",
        str(tiny_dataset),
        "--out",
        str(run_dir),
        "--steps",
        "1",
        "-s",
        "epoch_steps=1",
        "--quiet",
        "--threads",
        "1",
        *TINY,
    )
    assert r.exit_code == 0, r.output + r.stderr
    assert json.loads((run_dir / "config.json").read_text())["threads"] == 1


def test_train_an_explicit_set_threads_wins(monkeypatch, tmp_path: Path) -> None:
    seen = {}

    def fake_train_model(out, *, overrides, **kwargs):
        seen.update(overrides)
        return SimpleNamespace(result=SimpleNamespace(rank=0), messages=lambda: [])

    monkeypatch.setattr("mcdenoise.train.trainers.train_model", fake_train_model)
    out = str(tmp_path / "run")
    assert run("train", "--out", out, "--threads", "3", "-s", "threads=2").exit_code == 0
    assert seen["threads"] == "2"
    seen.clear()
    assert run("train", "--out", out, "--threads", "3").exit_code == 0
    assert seen["threads"] == "3"
    seen.clear()
    assert run("train", "--out", out).exit_code == 0
    assert "threads" not in seen  # the config's own value (0: the command's auto choice)


def test_render_threads_sets_mitsubas_pool(monkeypatch, tmp_path: Path) -> None:
    dr = pytest.importorskip("drjit")
    before = dr.thread_count()

    def fake_render_dataset(specs, config, random=None, samples_out=None):
        return SimpleNamespace(
            rendered=[], skipped=[], shard_jobs=0, variant=None, seconds=0.0, manifest="-"
        )

    monkeypatch.setattr("mcdenoise.render.generate.render_dataset", fake_render_dataset)
    try:
        r = run("render", "-o", str(tmp_path / "data"), "--threads", "1")
        assert r.exit_code == 0, r.output + r.stderr
        assert dr.thread_count() == 1 and torch.get_num_threads() == 1
    finally:
        dr.set_thread_count(before)


def test_a_far_too_slow_method_says_so_once_on_stderr(monkeypatch, tmp_path: Path) -> None:
    monkeypatch.setattr(threads, "_warned", set())
    monkeypatch.setattr(threads, "MIN_WARN_SECONDS", 0.0)
    monkeypatch.setitem(get_method("kpcn").recorded_speed, "kpcn", (1e-9, 1e-9))
    inputs = [str(SAMPLE), str(SAMPLE.with_name("dof_spp4.exr"))]
    r = run("denoise", *inputs, "-o", str(tmp_path), "--method", "kpcn", "--threads", "1")
    assert r.exit_code == 0, r.output + r.stderr
    lines = [ln for ln in r.stderr.splitlines() if "its recorded speed" in ln]
    assert len(lines) == 1 and lines[0].startswith("mcdenoise: warning: method kpcn took")
    assert "its recorded speed" not in r.stdout

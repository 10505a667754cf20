"""The command line as users meet it: one-line errors, exit codes, nothing half-written.

docs/hard-cases.md items 33 (bad arguments -> one line, non-zero exit, no traceback) and 34
(an interrupted folder run leaves complete outputs only), plus the happy paths of denoise /
info / eval.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from mcdenoise_cli.main import main

from mcdenoise.io import FeatureBuffers, load_buffers, save_buffers
from mcdenoise.io.atomic import TMP_PREFIX


def make_noisy(path: Path, *, size=(24, 20), seed=0, features=True) -> Path:
    """A small smooth image with noise, plus albedo/normal/depth and variance."""
    g = torch.Generator().manual_seed(seed)
    h, w = size
    yy, xx = torch.meshgrid(torch.linspace(0, 1, h), torch.linspace(0, 1, w), indexing="ij")
    clean = torch.stack([0.2 + 0.5 * xx, 0.3 + 0.4 * yy, 0.5 + 0.0 * xx])
    noisy = (clean + 0.1 * torch.randn(3, h, w, generator=g)).clamp_min(0)
    bufs = {"color": noisy, "color_var": torch.full((3, h, w), 0.01)}
    if features:
        bufs["albedo"] = torch.full((3, h, w), 0.7)
        bufs["normal"] = torch.stack([0 * xx, 0 * xx, 1 + 0 * xx])
        bufs["depth"] = (1.0 + xx).unsqueeze(0)
    save_buffers(path, FeatureBuffers(bufs, spp=4))
    return path


def run(*args: str):
    return CliRunner().invoke(main, list(args), catch_exceptions=False)


def one_line_error(result) -> str:
    """Assert the failure shape every bad input must have; return the message."""
    assert result.exit_code not in (0, None), result.output
    err = result.stderr.strip()
    assert "Traceback" not in result.output + err
    assert len(err.splitlines()) == 1, err
    return err


# --- happy paths ---------------------------------------------------------------------------


def test_denoise_one_file_records_method_and_time(tmp_path):
    src = make_noisy(tmp_path / "noisy.exr")
    out = tmp_path / "out.exr"
    r = run("denoise", str(src), "-o", str(out), "--method", "nlm")
    assert r.exit_code == 0, r.output
    got = load_buffers(out)
    assert got.shape == load_buffers(src).shape
    assert got.attributes["mcdenoise:method"] == "nlm"
    assert float(got.attributes["mcdenoise:seconds"]) > 0
    assert Path(got.attributes["mcdenoise:source"]).resolve() == src.resolve()
    assert torch.isfinite(got.color).all()


def test_denoise_default_output_name_and_best_method(tmp_path):
    src = make_noisy(tmp_path / "a.exr")
    r = run("denoise", str(src))
    assert r.exit_code == 0, r.output
    made = sorted(p.name for p in tmp_path.glob("a_*.exr"))
    assert len(made) == 1, made


def test_denoise_folder_with_all_methods(tmp_path):
    folder = tmp_path / "in"
    folder.mkdir()
    make_noisy(folder / "x.exr", seed=1)
    make_noisy(folder / "y.exr", seed=2, features=False)
    out = tmp_path / "out"
    r = run("denoise", str(folder), "-o", str(out), "--method", "nlm,cross-bilateral")
    assert r.exit_code == 0, r.output
    names = sorted(p.name for p in out.iterdir())
    assert names == ["x_cross-bilateral.exr", "x_nlm.exr", "y_cross-bilateral.exr", "y_nlm.exr"]


def test_info_text_and_json(tmp_path):
    src = make_noisy(tmp_path / "n.exr")
    r = run("info", str(src))
    assert r.exit_code == 0, r.output
    assert "albedo" in r.output and "mcdenoise" in r.output
    r = run("info", "--json", str(src))
    rec = json.loads(r.output)
    assert isinstance(rec, dict)


def test_methods_lists_filters():
    r = run("methods")
    assert r.exit_code == 0
    assert "nlm" in r.output and "cross-bilateral" in r.output


def test_eval_writes_report(tmp_path):
    ref = tmp_path / "ref"
    ref.mkdir()
    h, w = 24, 20
    yy, xx = torch.meshgrid(torch.linspace(0, 1, h), torch.linspace(0, 1, w), indexing="ij")
    clean = torch.stack([0.2 + 0.5 * xx, 0.3 + 0.4 * yy, 0.5 + 0.0 * xx])
    save_buffers(ref / "scene.exr", FeatureBuffers({"color": clean}))
    src = make_noisy(tmp_path / "scene_spp4.exr")
    out = tmp_path / "den"
    assert run("denoise", str(src), "-o", str(out), "-m", "nlm").exit_code == 0
    rep = tmp_path / "rep"
    r = run("eval", "--ref", str(ref), str(out), "-o", str(rep))
    assert r.exit_code == 0, r.output
    for name in ("report.html", "results.json", "results.csv"):
        assert (rep / name).is_file()


# --- docs/hard-cases.md item 33: bad arguments -----------------------------------------------


def test_missing_input(tmp_path):
    msg = one_line_error(run("denoise", str(tmp_path / "nope.exr")))
    assert "nope.exr" in msg


def test_folder_passed_as_file_to_info(tmp_path):
    msg = one_line_error(run("info", str(tmp_path)))
    assert str(tmp_path.name) in msg


def test_empty_folder(tmp_path):
    msg = one_line_error(run("denoise", str(tmp_path)))
    assert "no .exr" in msg


def test_output_equals_input(tmp_path):
    src = make_noisy(tmp_path / "n.exr")
    before = src.read_bytes()
    msg = one_line_error(run("denoise", str(src), "-o", str(src)))
    assert "input" in msg
    assert src.read_bytes() == before


@pytest.mark.skipif(os.geteuid() == 0, reason="root can write anywhere")
def test_unwritable_output_folder(tmp_path):
    src = make_noisy(tmp_path / "n.exr")
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        msg = one_line_error(run("denoise", str(src), "-o", str(locked / "o.exr")))
        assert "writable" in msg
    finally:
        locked.chmod(0o700)


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux procfs")
def test_unwritable_output_even_for_root(tmp_path):
    """/proc/self accepts no new files, whoever runs the tests (CI may run as root)."""
    src = make_noisy(tmp_path / "n.exr")
    msg = one_line_error(run("denoise", str(src), "-o", "/proc/self/o.exr"))
    assert "/proc/self" in msg
    other = make_noisy(tmp_path / "n_other.exr", seed=3)
    msg = one_line_error(run("eval", "--ref", str(src), str(other), "-o", "/proc/self/report"))
    assert "/proc/self/report" in msg and "Errno" not in msg


def test_output_in_a_missing_folder_creates_it_after_the_method_ran(tmp_path):
    src = make_noisy(tmp_path / "n.exr")
    out = tmp_path / "no" / "such" / "o.exr"
    r = run("denoise", str(src), "-m", "nlm", "-o", str(out))
    assert r.exit_code == 0, r.output
    assert out.is_file()
    # a run that fails (kpcn refuses a file without albedo) leaves no folder behind
    bare = tmp_path / "bare.exr"
    save_buffers(bare, FeatureBuffers({"color": torch.rand(3, 8, 8)}))
    gone = tmp_path / "never" / "o.exr"
    msg = one_line_error(run("denoise", str(bare), "-m", "kpcn", "-o", str(gone)))
    assert "albedo" in msg
    assert not gone.parent.exists()


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux procfs")
def test_an_output_folder_that_cannot_be_created_is_one_line(tmp_path):
    """/proc/self takes no new folders, whoever runs the tests (CI may run as root)."""
    src = make_noisy(tmp_path / "n.exr")
    msg = one_line_error(run("denoise", str(src), "-m", "nlm", "-o", "/proc/self/new/o.exr"))
    assert "/proc/self" in msg and "Traceback" not in msg


def test_output_not_exr(tmp_path):
    src = make_noisy(tmp_path / "n.exr")
    (tmp_path / "o.png").write_bytes(b"")
    one_line_error(run("denoise", str(src), "-o", str(tmp_path / "o.png")))


@pytest.mark.parametrize(
    "param",
    [
        "kernel_size=4",
        "kernel_size=-3",
        "kernel_size=0",
        "sigma_color=0",
        "sigma_color=-1",
        "kernel_size=abc",
        "nonsense=1",
        "novalue",
    ],
)
def test_bad_parameters(tmp_path, param):
    src = make_noisy(tmp_path / "n.exr")
    out = tmp_path / "o.exr"
    msg = one_line_error(
        run("denoise", str(src), "-o", str(out), "-m", "cross-bilateral", "-p", param)
    )
    assert param.split("=")[0] in msg
    assert ("has no parameter" in msg) == param.startswith("nonsense")
    assert not out.exists()
    assert not list(tmp_path.glob(TMP_PREFIX + "*"))


@pytest.mark.parametrize(
    "param", ["search_radius=-1", "k=0", "k=-2", "patch_radius=-1", "search_radius=100000"]
)
def test_bad_nlm_parameters(tmp_path, param):
    src = make_noisy(tmp_path / "n.exr")
    msg = one_line_error(
        run("denoise", str(src), "-o", str(tmp_path / "o.exr"), "-m", "nlm", "-p", param)
    )
    assert param.split("=")[0] in msg
    assert "has no parameter" not in msg  # rejected for its value, not its name


def test_unknown_method(tmp_path):
    src = make_noisy(tmp_path / "n.exr")
    msg = one_line_error(run("denoise", str(src), "-m", "magic"))
    assert "magic" in msg and "nlm" in msg


def test_missing_feature_names_channels(tmp_path, monkeypatch):
    """A method needing albedo on a colour-only file: the one-line error names the missing
    buffer and lists what the file does have (docs/hard-cases.md item 4)."""
    from mcdenoise import registry

    needs_albedo = registry.Method(
        name="needs-albedo",
        summary="test",
        requires=("color", "albedo"),
        uses=(),
        defaults={},
        run=lambda b, p, d: b["color"],
    )
    monkeypatch.setitem(registry._REGISTRY, "needs-albedo", needs_albedo)
    src = make_noisy(tmp_path / "n.exr", features=False)
    msg = one_line_error(
        run("denoise", str(src), "-o", str(tmp_path / "o.exr"), "-m", "needs-albedo")
    )
    assert "albedo" in msg and "color" in msg and "R" in msg
    assert not (tmp_path / "o.exr").exists()


def test_corrupt_input_does_not_replace_existing_output(tmp_path):
    bad = tmp_path / "bad.exr"
    bad.write_bytes(b"\x76\x2f\x31\x01" + os.urandom(200))
    out = tmp_path / "o.exr"
    out.write_bytes(b"previous result")
    one_line_error(run("denoise", str(bad), "-o", str(out)))
    assert out.read_bytes() == b"previous result"


def test_real_process_prints_one_line_and_exit_code(tmp_path):
    """Through a real interpreter: no traceback reaches the terminal."""
    proc = subprocess.run(
        [sys.executable, "-m", "mcdenoise_cli.main", "denoise", str(tmp_path / "missing.exr")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 1
    assert "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    assert proc.stderr.startswith("mcdenoise: error:")


# --- docs/hard-cases.md item 34: interrupted folder run --------------------------------------


def test_interrupted_folder_run_leaves_only_complete_outputs(tmp_path):
    folder = tmp_path / "in"
    folder.mkdir()
    for i in range(3):
        make_noisy(folder / f"im{i}.exr", seed=i, size=(64, 64))
    out = tmp_path / "out"
    code = f"""
import sys, signal, os
# a shell's background jobs start with SIGINT ignored; a terminal's Ctrl-C is what we mimic
signal.signal(signal.SIGINT, signal.default_int_handler)
import mcdenoise.output as dn
real = dn.denoise
count = [0]
def slow(*a, **k):
    count[0] += 1
    if count[0] == 2:
        os.kill(os.getpid(), signal.SIGINT)
    return real(*a, **k)
dn.denoise = slow
from mcdenoise_cli.main import main
sys.exit(main(["denoise", {str(folder)!r}, "-o", {str(out)!r}, "-m", "nlm"]))
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 130, proc.stderr
    assert "Traceback" not in proc.stderr
    written = sorted(out.glob("*.exr"))
    assert [p.name for p in written] == ["im0_nlm.exr"]
    assert not list(out.glob(TMP_PREFIX + "*"))
    got = load_buffers(written[0])
    assert np.isfinite(got.color.numpy()).all()


def test_eval_of_a_part_compares_with_the_same_part(tmp_path):
    """Outputs made from one level of a multi-part file (``--part spp16``) are compared with
    that level's noisy row, not with the file's first part."""
    import json as _json

    from mcdenoise.io import save_buffers_parts

    h, w = 24, 20
    yy, xx = torch.meshgrid(torch.linspace(0, 1, h), torch.linspace(0, 1, w), indexing="ij")
    clean = torch.stack([0.2 + 0.5 * xx, 0.3 + 0.4 * yy, 0.5 + 0.0 * xx])
    g = torch.Generator().manual_seed(0)
    parts = {}
    for name, sigma, spp in (("spp4", 0.2, 4), ("spp16", 0.05, 16)):
        noisy = (clean + sigma * torch.randn(3, h, w, generator=g)).clamp_min(0)
        parts[name] = FeatureBuffers({"color": noisy}, spp=spp)
    (tmp_path / "ref").mkdir()
    save_buffers(tmp_path / "ref" / "scene.exr", FeatureBuffers({"color": clean}))
    save_buffers_parts(tmp_path / "scene.exr", parts)
    out = tmp_path / "den"
    for part in ("spp4", "spp16"):
        r = run("denoise", str(tmp_path / "scene.exr"), "--part", part, "-m", "nlm", "-o", str(out))
        assert r.exit_code == 0, r.output
    assert sorted(p.name for p in out.iterdir()) == ["scene_spp16_nlm.exr", "scene_spp4_nlm.exr"]
    rep = tmp_path / "rep"
    assert run("eval", "--ref", str(tmp_path / "ref"), str(out), "-o", str(rep)).exit_code == 0
    records = _json.loads((rep / "results.json").read_text())["records"]
    noisy = {r["spp"]: r for r in records if r["method"] == "noisy"}
    assert sorted(noisy) == [4, 16]
    assert noisy[16]["metrics"]["relmse"] < noisy[4]["metrics"]["relmse"]
    for r in records:
        if r["method"] == "nlm":
            base = noisy[r["spp"]]["metrics"]["relmse"]
            assert r["relmse_ratio"] == pytest.approx(r["metrics"]["relmse"] / base)

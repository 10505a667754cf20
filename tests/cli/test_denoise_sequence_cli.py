"""``mcdenoise denoise SEQ_DIR --method <temporal>`` as users meet it: outputs frame by frame
with progress over frames, one-line refusals of bad sequences with nothing written, Ctrl-C
keeping the finished frames and a re-run writing the rest (issue 23, item 1).

The temporal method is a toy registered for the test (a running mean of the colour over the
frames), so what is tested is the command, not a denoiser.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import torch
from fast_methods import add_methods, fast_method, run_cli

from mcdenoise.io import FeatureBuffers, load_buffers, save_buffers
from mcdenoise.io.atomic import TMP_PREFIX
from mcdenoise.method import Method

#: The toy, as source: the interrupt test registers it in a fresh interpreter too.
TOY = """
def running_mean(frames, params, device):
    total, n = None, 0
    for f in frames:
        c = f["color"]
        total = c if total is None else total + c
        n += 1
        yield total / n
"""
namespace: dict = {}
exec(TOY, namespace)  # the test's own source, above
running_mean = namespace["running_mean"]


def toy_method() -> Method:
    return Method(
        "runmean", "running mean (test)", ("color",), ("motion",), {}, None,
        temporal=True, run_sequence=running_mean,
    )  # fmt: skip


def colour(t: int) -> torch.Tensor:
    return torch.rand(3, 6, 8, generator=torch.Generator().manual_seed(t)) + 0.1


def frames(folder: Path, numbers=range(4), *, motion: bool = True) -> Path:
    """Frames named and attributed as ``mcdenoise render --frames`` writes them."""
    (folder / "ref").mkdir(parents=True)
    for t in numbers:
        b = {"color": colour(t)}
        if motion:
            b["motion"] = torch.zeros(2, 6, 8)
        save_buffers(
            folder / f"frame_{t:04d}.exr",
            FeatureBuffers(b, spp=4),
            attributes={"mcdenoise:frame": t},
        )
        save_buffers(folder / "ref" / f"frame_{t:04d}.exr", FeatureBuffers({"color": colour(t)}))
    return folder


@pytest.fixture
def toy(monkeypatch: pytest.MonkeyPatch) -> None:
    add_methods(monkeypatch, toy_method(), fast_method("box3"), only=True)


def one_line_error(result) -> str:
    assert result.exit_code == 1, result.output
    err = result.stderr.strip()
    assert "Traceback" not in result.output and len(err.splitlines()) == 1, err
    assert err.startswith("mcdenoise: error: ")
    return err


def test_a_sequence_is_denoised_frame_by_frame_with_progress(toy, tmp_path: Path) -> None:
    seq = frames(tmp_path / "seq")
    out = tmp_path / "out"
    r = run_cli("denoise", seq, "-o", out, "--method", "runmean", "--progress")
    assert r.exit_code == 0, r.output
    lines = r.stdout.strip().splitlines()
    assert [ln.split()[0] for ln in lines] == [
        str(out / f"frame_{t:04d}_runmean.exr") for t in range(4)
    ]
    assert "denoise: 4 frames" in r.stderr  # progress over frames (a log: plain lines)
    total = torch.zeros(3, 6, 8)
    for t in range(4):
        total += colour(t)
        got = load_buffers(out / f"frame_{t:04d}_runmean.exr")["color"]
        torch.testing.assert_close(got, total / (t + 1))


def test_methods_says_which_are_temporal(toy) -> None:
    r = run_cli("methods")
    blocks = r.stdout.split("\n\ndefault")[0].split("\nrunmean")
    assert "temporal" not in blocks[0]  # box3, listed first
    assert "temporal: a folder of frames is one sequence" in blocks[1]


@pytest.mark.parametrize(
    ("numbers", "motion", "needle"),
    [
        ((0, 1, 3), True, "frame 2 is missing (between frame_0001.exr and frame_0003.exr)"),
        ((0, 1, 2), False, "method 'runmean' needs motion vectors in every frame; frame_0000.exr has none"),
    ],
)  # fmt: skip
def test_a_bad_sequence_is_one_line_and_nothing_is_written(
    toy, tmp_path: Path, numbers, motion, needle
) -> None:
    seq = frames(tmp_path / "seq", numbers, motion=motion)
    msg = one_line_error(run_cli("denoise", seq, "-o", tmp_path / "out", "-m", "runmean"))
    assert needle in msg
    assert not (tmp_path / "out").exists()
    # the same folder is still a batch of stills for a per-frame method
    r = run_cli("denoise", seq, "-o", tmp_path / "out", "-m", "box3")
    assert r.exit_code == 0 and len(list((tmp_path / "out").glob("*.exr"))) == len(numbers)


def test_frames_of_different_sizes_are_one_line(toy, tmp_path: Path) -> None:
    seq = frames(tmp_path / "seq", (0, 1))
    small = FeatureBuffers({"color": torch.ones(3, 4, 4), "motion": torch.zeros(2, 4, 4)})
    save_buffers(seq / "frame_0002.exr", small, attributes={"mcdenoise:frame": 2})
    msg = one_line_error(run_cli("denoise", seq, "-o", tmp_path / "out", "-m", "runmean"))
    assert "frames of different sizes: frame_0000.exr is 8x6, frame_0002.exr is 4x4" in msg


def test_ctrl_c_keeps_finished_frames_and_a_rerun_writes_the_rest(tmp_path: Path) -> None:
    """A real interpreter, a real SIGINT after frame 1 is written: exit 130, frames 0 and 1
    complete, no temporary left; the re-run writes frames 2 and 3 only."""
    seq = frames(tmp_path / "seq")
    out = tmp_path / "out"
    code = f"""
import os, signal, sys
signal.signal(signal.SIGINT, signal.default_int_handler)
{TOY}
from mcdenoise import registry
from mcdenoise.method import Method
import mcdenoise.batch as dn
registry.register(Method("runmean", "t", ("color",), ("motion",), {{}}, None,
                         temporal=True, run_sequence=running_mean))
STOP = "stop" in sys.argv
real = dn.write_result
written = []
def spy(src, dst, *a, **k):
    res = real(src, dst, *a, **k)
    written.append(dst.name)
    print("wrote", dst.name, file=sys.stderr, flush=True)
    if len(written) == 2 and STOP:
        os.kill(os.getpid(), signal.SIGINT)
    return res
dn.write_result = spy
from mcdenoise_cli.main import main
sys.argv = sys.argv[:1]
sys.exit(main(["denoise", {str(seq)!r}, "-o", {str(out)!r}, "-m", "runmean", "--no-progress"]))
"""

    def run(*extra: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, "-c", code, *extra], capture_output=True, text=True, timeout=300
        )

    first = run("stop")
    assert first.returncode == 130, first.stderr
    assert "Traceback" not in first.stderr
    assert sorted(p.name for p in out.iterdir()) == [
        "frame_0000_runmean.exr",
        "frame_0001_runmean.exr",
    ]
    assert not list(out.glob(TMP_PREFIX + "*"))
    second = run()
    assert second.returncode == 0, second.stderr
    assert [ln for ln in second.stderr.splitlines() if ln.startswith("wrote")] == [
        "wrote frame_0002_runmean.exr",
        "wrote frame_0003_runmean.exr",
    ]
    assert second.stderr.count("is done (an earlier run wrote it)") == 2
    total = torch.zeros(3, 6, 8)
    for t in range(4):
        total += colour(t)
        got = load_buffers(out / f"frame_{t:04d}_runmean.exr")["color"]
        torch.testing.assert_close(got, total / (t + 1))  # as one uninterrupted run

"""Nothing the user owns may be lost (issue 33, items 3, 4 and 5).

Each test is a case that lost or mixed up a user's data before the fix:

* a full disk gave a truncated EXR reported as written (OpenImageIO's ``close()`` returns
  true after a failed flush), and left 0-byte ``estimate.json/csv/html``;
* JSON files held bare ``NaN`` (not JSON: strict readers refuse the file);
* ``denoise coll -o coll -m nlm`` overwrote the user's ``coll/a_nlm.exr``, and a folder scan
  took the tool's own earlier outputs for inputs;
* two ``eval --experiment`` processes on one folder both ran every unit, timed against each
  other, and a shard on one host swept another host's in-progress temporary file.

A full disk is simulated three ways: OpenImageIO's writer cut short behind a ``close()`` that
says true; ``os.write`` failing with ENOSPC after some bytes; and, where the machine allows
(root, ``mount``), a real tmpfs a little too small for the output.
"""

from __future__ import annotations

import errno
import importlib.util
import json
import math
import os
import subprocess
import sys
import textwrap
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from mcdenoise_cli.main import main

from mcdenoise import registry
from mcdenoise.errors import ExrError, McdenoiseError
from mcdenoise.io import FeatureBuffers, save_buffers
from mcdenoise.io.atomic import TMP_PREFIX, sweep_stale_temporaries
from mcdenoise.io.exr import read_exr
from mcdenoise.io.exr_write import write_exr
from mcdenoise.method import Method


def run(*args: Any):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def temporaries(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob(f"{TMP_PREFIX}*"))


def box3(b: FeatureBuffers, p: Mapping[str, Any], d: torch.device) -> torch.Tensor:
    x = torch.nn.functional.pad(b["color"][None], (1, 1, 1, 1), mode="replicate")
    return torch.nn.functional.avg_pool2d(x, 3, stride=1)[0]


@pytest.fixture
def box(monkeypatch: pytest.MonkeyPatch) -> str:
    """A fast method named ``box`` (registered for one test)."""
    method = Method(
        name="box", summary="3x3 box (test)", requires=("color",), uses=(), defaults={}, run=box3
    )
    monkeypatch.setitem(registry._REGISTRY, "box", method)
    return "box"


def noisy_input(path: Path, size: int = 24, seed: int = 0) -> Path:
    rng = np.random.default_rng(seed)
    color = torch.from_numpy(rng.random((3, size, size), dtype=np.float32))
    save_buffers(path, FeatureBuffers({"color": color}, spp=4))
    return path


# --- item 3: a full disk never leaves a corrupt file reported as written --------------------


class _FlushFailsSilently:
    """OpenImageIO's ImageOutput whose file loses its last ``lost`` bytes at ``close()``,
    which still returns true: what a full disk does to its final flush."""

    def __init__(self, real: Any, lost: int) -> None:
        self.real, self.lost, self.name = real, lost, ""

    def open(self, name: str, *args: Any) -> bool:
        self.name = name
        return self.real.open(name, *args)

    def close(self) -> bool:
        self.real.close()
        size = os.path.getsize(self.name)
        os.truncate(self.name, max(size - self.lost, 0))
        return True

    def __getattr__(self, name: str) -> Any:
        return getattr(self.real, name)


@pytest.fixture
def cut_flush(monkeypatch: pytest.MonkeyPatch):
    """``cut_flush(lost)``: from now on every EXR written loses its last ``lost`` bytes in a
    ``close()`` that returns true."""
    import OpenImageIO as oiio

    from mcdenoise.io import exr_write

    def install(lost: int) -> None:
        class Output:
            @staticmethod
            def create(name: str) -> Any:
                return _FlushFailsSilently(oiio.ImageOutput.create(name), lost)

        class Module:
            def __getattr__(self, name: str) -> Any:
                return Output if name == "ImageOutput" else getattr(oiio, name)

        monkeypatch.setattr(exr_write, "_oiio", lambda: Module())

    return install


def test_an_exr_cut_short_behind_a_successful_close_is_refused(tmp_path, cut_flush):
    target = tmp_path / "out.exr"
    write_exr(target, {"Y": np.ones((8, 8), np.float32)})
    before = target.read_bytes()
    for lost in (1, 100, 5000):
        cut_flush(lost)
        with pytest.raises(ExrError) as err:
            write_exr(target, {"Y": np.zeros((64, 48), np.float32)})
        msg = str(err.value)
        assert str(target) in msg and "incomplete" in msg and "\n" not in msg
        assert TMP_PREFIX not in msg  # the final name, not the temporary one
        assert target.read_bytes() == before  # the old file, untouched
        assert temporaries(tmp_path) == []


def test_denoise_on_a_full_disk_exits_non_zero_and_reports_nothing_written(
    tmp_path, box, cut_flush
):
    src = noisy_input(tmp_path / "a.exr")
    out = tmp_path / "out"
    out.mkdir()
    cut_flush(1)
    r = run("denoise", src, "-m", box, "-o", out)
    assert r.exit_code == 1
    err = r.stderr.strip()
    assert len(err.splitlines()) == 1 and str(out / "a_box.exr") in err
    assert r.stdout == ""  # the output is not reported as written
    assert list(out.iterdir()) == []


def _failing_write(after: int):
    """``os.write`` that accepts ``after`` bytes in all, then fails with ENOSPC."""
    real = os.write
    state = {"left": after}

    def write(fd: int, data: Any) -> int:
        if state["left"] <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        n = real(fd, bytes(data)[: state["left"]])  # a short write first
        state["left"] -= n
        return n

    return write


def test_text_written_on_a_full_disk_leaves_the_old_file(tmp_path, monkeypatch):
    from mcdenoise.io.atomic import write_text_atomic

    target = tmp_path / "record.json"
    target.write_text('{"old": true}\n')
    monkeypatch.setattr(os, "write", _failing_write(after=1000))
    with pytest.raises(OSError) as err:
        write_text_atomic(target, json.dumps({"values": list(range(5000))}))
    monkeypatch.undo()
    assert isinstance(err.value, McdenoiseError)  # one line for the CLI
    assert str(target) in str(err.value) and "No space left" in str(err.value)
    assert target.read_text() == '{"old": true}\n'
    assert temporaries(tmp_path) == []


def test_the_estimate_report_on_a_full_disk_leaves_no_partial_file(tmp_path, monkeypatch):
    from mcdenoise.eval.estimate import write_estimate_report

    rows = [
        {"scene": f"s{i}", "spp": 4, "method": "nlm", "relmse_estimated": 0.01 * i}
        for i in range(200)
    ]
    monkeypatch.setattr(os, "write", _failing_write(after=2000))
    with pytest.raises(OSError) as err:
        write_estimate_report(rows, tmp_path / "rep")
    monkeypatch.undo()
    assert "estimate.json" in str(err.value)
    # no 0-byte or cut estimate.json/csv/html, no temporary
    assert sorted(p.name for p in (tmp_path / "rep").iterdir()) == []


def _mount_tmpfs(folder: Path, size: int) -> bool:
    folder.mkdir(parents=True, exist_ok=True)
    r = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)],
        capture_output=True,
    )
    return r.returncode == 0


def _umount(folder: Path) -> None:
    subprocess.run(["umount", str(folder)], capture_output=True)


def test_a_real_tiny_filesystem_gets_a_complete_output_or_none(tmp_path, box):
    """For every free room around the output's size, ``denoise`` either writes the complete
    file (exit 0) or nothing (one line naming it, exit 1): never a cut file reported as
    written. Needs ``mount -t tmpfs`` (root); skipped elsewhere."""
    src = noisy_input(tmp_path / "a.exr", size=160)
    probe = tmp_path / "probe.exr"
    assert run("denoise", src, "-m", box, "-o", probe, "--compression", "none").exit_code == 0
    size = probe.stat().st_size
    expected = read_exr(probe).pixels
    disk = tmp_path / "disk"
    if not _mount_tmpfs(disk, 1 << 20):
        pytest.skip("cannot mount a tmpfs here (needs root)")
    _umount(disk)
    page = 4096
    outcomes = []
    for room in range(size // page * page - 6 * page, size + 2 * page, page):
        assert _mount_tmpfs(disk, room)
        try:
            out = disk / "o.exr"
            r = run("denoise", src, "-m", box, "-o", out, "--compression", "none")
            names = sorted(p.name for p in disk.iterdir())
            if r.exit_code == 0:
                assert names == ["o.exr"]
                got = read_exr(out).pixels
                assert all(np.array_equal(got[c], expected[c]) for c in expected)
            else:
                assert r.exit_code == 1 and names == []  # no cut file, no temporary
                err = r.stderr.strip()
                assert len(err.splitlines()) == 1 and str(out) in err, err
            outcomes.append(r.exit_code)
        finally:
            _umount(disk)
    assert 0 in outcomes and 1 in outcomes  # the sizes tried straddle the output's


def test_json_files_never_hold_nan(tmp_path):
    from mcdenoise.eval.estimate import write_estimate_report
    from mcdenoise.train.checkpoint import RunFolder

    def strict(text: str) -> Any:
        def refuse(name: str) -> Any:
            raise ValueError(f"not JSON: {name}")

        return json.loads(text, parse_constant=refuse)

    row = {"scene": "s", "spp": 4, "method": "nlm", "relmse_estimated": math.nan}
    paths = write_estimate_report([row], tmp_path / "rep")
    data = strict(paths["json"].read_text(encoding="utf-8"))
    assert data["rows"][0]["relmse_estimated"] is None  # not estimated: null, as elsewhere

    run_folder = RunFolder(tmp_path / "run")
    run_folder.create()
    run_folder.append_metrics({"step": 1, "val_loss": math.nan, "best_val_loss": math.inf})
    line = strict(run_folder.metrics_path.read_text().splitlines()[0])
    assert line["val_loss"] is None and line["best_val_loss"] is None
    assert run_folder.read_metrics()[0]["step"] == 1


# --- item 4: outputs never overwrite inputs -------------------------------------------------


def test_a_batch_never_writes_over_its_own_inputs(tmp_path, box):
    coll = tmp_path / "coll"
    coll.mkdir()
    noisy_input(coll / "a.exr", seed=1)
    noisy_input(coll / "a_box.exr", seed=2)  # the user's file, named like an output
    before = {p.name: p.read_bytes() for p in coll.iterdir()}
    for args in (["-m", box, "-o", coll], ["-m", box], ["-o", coll]):  # the last: auto
        r = run("denoise", coll, *args)
        assert r.exit_code == 1, r.output
        err = r.stderr.strip()
        assert len(err.splitlines()) == 1 and "a_box.exr" in err and "overwrite" in err
        assert {p.name: p.read_bytes() for p in coll.iterdir()} == before  # nothing written
    # elsewhere is fine
    r = run("denoise", coll, "-m", box, "-o", tmp_path / "out", "--no-progress")
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a_box.exr", "a_box_box.exr"]


def test_an_output_named_as_its_own_input_is_refused_in_plain_words(tmp_path, box):
    """``denoise a.exr -o a.exr`` (or ``-o ./coll/../coll/a.exr``, or a link to it): one line
    naming the file and saying to choose another name, not "write the outputs into another
    folder" (review of issue 33 item 4)."""
    coll = tmp_path / "coll"
    coll.mkdir()
    noisy_input(coll / "a.exr", seed=1)
    (tmp_path / "link.exr").symlink_to(coll / "a.exr")
    before = (coll / "a.exr").read_bytes()
    for out in (coll / "a.exr", tmp_path / "coll" / ".." / "coll" / "a.exr", tmp_path / "link.exr"):
        r = run("denoise", coll / "a.exr", "-m", box, "-o", out)
        assert r.exit_code == 1, r.output
        err = r.stderr.strip()
        assert len(err.splitlines()) == 1 and err.startswith(
            f"mcdenoise: error: {coll / 'a.exr'}: "
        )
        assert "would overwrite this input" in err and "another file name or a folder" in err
        assert (coll / "a.exr").read_bytes() == before


def test_a_folder_scan_skips_the_tools_own_outputs(tmp_path, box):
    coll = tmp_path / "coll"
    coll.mkdir()
    noisy_input(coll / "a.exr")
    assert run("denoise", coll, "-m", box).exit_code == 0
    assert sorted(p.name for p in coll.iterdir()) == ["a.exr", "a_box.exr"]
    again = run("denoise", coll, "-m", box)  # the same again: a_box.exr is not an input
    assert again.exit_code == 0, again.output
    assert sorted(p.name for p in coll.iterdir()) == ["a.exr", "a_box.exr"]

    # the scan reads headers only: no pixel of any file
    from mcdenoise import denoise_files
    from mcdenoise.io import exr

    def no_pixels(*a: Any, **k: Any) -> Any:
        raise AssertionError("a folder scan read pixels")

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(exr, "read_exr", no_pixels)
        mp.setattr(exr, "_oiio", no_pixels)  # not even OpenImageIO's header reader
        assert denoise_files.collect_inputs([coll]) == [coll / "a.exr"]
        everything = denoise_files.collect_inputs([coll], include_outputs=True)
        assert everything == [coll / "a.exr", coll / "a_box.exr"]

    # asked for, outputs are inputs too (into another folder: no overwrite)
    out = tmp_path / "out"
    r = run("denoise", coll, "-m", box, "-o", out, "--include-outputs", "--no-progress")
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in out.iterdir()) == ["a_box.exr", "a_box_box.exr"]
    # a folder of outputs only says how to include them
    only = run("denoise", out, "-m", box, "-o", tmp_path / "x")
    assert only.exit_code == 1 and "--include-outputs" in only.stderr
    assert "--include-outputs" in run("denoise", "--help").output


# --- item 5: one run per experiment folder; temporaries of other hosts kept -----------------


def _synthetic():
    """tests/experiments/synthetic_data.py (a render folder without Mitsuba)."""
    path = Path(__file__).resolve().parents[1] / "experiments" / "synthetic_data.py"
    spec = importlib.util.spec_from_file_location("_synthetic_data_for_safety", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def experiment(tmp_path, box, monkeypatch) -> Path:
    monkeypatch.setattr(
        "mcdenoise.experiments.plots.plots_unavailable", lambda: "not drawn in tests"
    )
    _synthetic().make_render_folder(tmp_path / "rendered", scenes=("alpha",), spp=(1, 2))
    spec = tmp_path / "exp.toml"
    spec.write_text(
        textwrap.dedent(
            f"""
            name = "lock"
            methods = ["{box}"]
            metrics = ["relmse"]
            repetitions = 1
            warmup = 0
            [scenes]
            folder = "rendered"
            [report]
            strip_spp = 2
            """
        ),
        encoding="utf-8",
    )
    return spec


_HOLDER = """
import sys, time
from mcdenoise.io.lockfile import LockFile
with LockFile(sys.argv[1], sys.argv[2]):
    print("holding", flush=True)
    time.sleep(120)
"""


def _hold(lock: Path, what: str) -> subprocess.Popen:
    """Another live process on this host holding ``lock``."""
    child = subprocess.Popen(
        [sys.executable, "-c", _HOLDER, str(lock), what], stdout=subprocess.PIPE, text=True
    )
    assert child.stdout is not None and child.stdout.readline().strip() == "holding"
    return child


def _stop(child: subprocess.Popen) -> None:
    child.kill()
    child.wait(timeout=30)
    if child.stdout is not None:
        child.stdout.close()


def test_a_second_run_on_one_experiment_folder_is_refused(tmp_path, experiment):
    out = tmp_path / "exp"
    child = _hold(out / "work" / "experiment.lock", "an experiment run")
    try:
        r = run("eval", "--experiment", experiment, "-o", out)
        assert r.exit_code == 1, r.output
        err = r.stderr.strip()
        assert len(err.splitlines()) == 1 and "Traceback" not in r.output
        assert f"process {child.pid}" in err and "in use" in err
        assert not list((out / "work").glob("*/spp*/*.json"))  # no unit ran
        # a shard cannot start beside a plain run either
        shard = run("eval", "--experiment", experiment, "-o", out, "--shard", "1/2")
        assert shard.exit_code == 1 and f"process {child.pid}" in shard.stderr
    finally:
        _stop(child)
    # the holder died without cleaning up (SIGKILL): its lock is stale and taken over
    assert (out / "work" / "experiment.lock").exists()
    r = run("eval", "--experiment", experiment, "-o", out)
    assert r.exit_code == 0, r.output
    assert not (out / "work" / "experiment.lock").exists()


def test_shards_share_the_folder_but_not_a_shard(tmp_path, experiment):
    out = tmp_path / "exp"
    other = _hold(out / "work" / "shards" / "shard-2-of-2.lock", "shard 2/2")
    try:
        first = run("eval", "--experiment", experiment, "-o", out, "--shard", "1/2")
        assert first.exit_code == 0, first.output  # shard 1 runs beside shard 2
        again = run("eval", "--experiment", experiment, "-o", out, "--shard", "2/2")
        assert again.exit_code == 1 and f"process {other.pid}" in again.stderr
        plain = run("eval", "--experiment", experiment, "-o", out)
        assert plain.exit_code == 1 and "shard 2/2" in plain.stderr
    finally:
        _stop(other)


def test_locks_of_other_hosts_are_kept_until_silent_too_long(tmp_path):
    from mcdenoise.io.lockfile import STALE_SECONDS, LockError, LockFile

    lock = tmp_path / "experiment.lock"
    holder = {"host": "elsewhere", "pid": 1, "started": "t", "what": "shard 1/2", "token": "x"}
    lock.write_text(json.dumps(holder))
    with pytest.raises(LockError, match="process 1 on elsewhere"):
        LockFile(lock, "a run", heartbeat=None).acquire()
    old = time.time() - STALE_SECONDS - 60
    os.utime(lock, (old, old))  # its host stopped touching it: taken over
    taken = LockFile(lock, "a run", heartbeat=None)
    taken.acquire()
    try:
        taken.check()
        assert json.loads(lock.read_text())["pid"] == os.getpid()
    finally:
        taken.release()
    assert not lock.exists()


_WRITER = """
import socket, sys, os, signal
socket.gethostname = lambda: sys.argv[2]  # this process stands for a writer on that host
from mcdenoise.io.atomic import atomic_path
with atomic_path(sys.argv[1]) as tmp:
    tmp.write_bytes(b"half of an image")
    os.kill(os.getpid(), signal.SIGKILL)  # killed mid-write: its temporary stays
"""


def _orphan(folder: Path, host: str) -> Path:
    """The temporary a writer on ``host`` left in ``folder`` (its PID is gone here)."""
    before = set(folder.iterdir())
    subprocess.run([sys.executable, "-c", _WRITER, str(folder / "o.exr"), host])
    (tmp,) = set(folder.iterdir()) - before
    assert tmp.name.startswith(TMP_PREFIX)
    return tmp


def test_another_hosts_temporary_is_not_swept(tmp_path):
    import socket

    theirs = _orphan(tmp_path, "node-b")  # in progress there, for all we know here
    ours = _orphan(tmp_path, socket.gethostname())  # dead here: an orphan
    assert "node-b" in theirs.name
    removed = sweep_stale_temporaries(tmp_path)
    assert removed == [ours] and theirs.exists()
    old = time.time() - 2 * 3600  # untouched for two hours: an orphan whoever wrote it
    os.utime(theirs, (old, old))
    assert sweep_stale_temporaries(tmp_path) == [theirs]

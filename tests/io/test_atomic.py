"""Atomic writes (docs/hard-cases.md item 12): old or new file, never a partial one, no stray
temporaries."""

from __future__ import annotations

import subprocess
import sys

import pytest

from mcdenoise.io.atomic import TMP_PREFIX, atomic_path, host_tag, write_text_atomic


def test_failed_write_keeps_old_file_and_leaves_no_temp(tmp_path):
    target = tmp_path / "a.json"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("boom")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]


def test_keyboard_interrupt_leaves_no_temp(tmp_path):
    target = tmp_path / "a.txt"
    with pytest.raises(KeyboardInterrupt), atomic_path(target) as tmp:
        tmp.write_text("x")
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_temp_name_carries_pid_host_and_suffix(tmp_path):
    import os

    with atomic_path(tmp_path / "img.exr", verify=lambda _: None) as tmp:  # not a real EXR
        assert tmp.name.startswith(f"{TMP_PREFIX}{os.getpid()}@{host_tag()}~")
        assert tmp.suffix == ".exr"
        tmp.write_bytes(b"1")


def test_temporaries_of_dead_writers_are_swept_live_ones_kept(tmp_path):
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        capture_output=True,
        text=True,
        check=True,
    )
    dead_pid = int(dead.stdout)
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        stale = tmp_path / f"{TMP_PREFIX}{dead_pid}@{host_tag()}~abc.exr"
        busy = tmp_path / f"{TMP_PREFIX}{live.pid}@{host_tag()}~def.exr"
        stale.write_bytes(b"partial")
        busy.write_bytes(b"in progress")
        write_text_atomic(tmp_path / "out.txt", "done")
        assert not stale.exists()
        assert busy.exists()
        assert (tmp_path / "out.txt").read_text() == "done"
    finally:
        live.kill()
        live.wait()


def test_new_file_gets_umask_permissions_replaced_file_keeps_its_mode(tmp_path):
    import os
    import stat

    mask = os.umask(0o022)
    try:
        write_text_atomic(tmp_path / "new.txt", "x")
        assert stat.S_IMODE((tmp_path / "new.txt").stat().st_mode) == 0o644
        old = tmp_path / "old.txt"
        old.write_text("old")
        old.chmod(0o640)
        write_text_atomic(old, "new")
        assert stat.S_IMODE(old.stat().st_mode) == 0o640
    finally:
        os.umask(mask)


def test_names_with_impossible_pids_never_break_the_sweep(tmp_path):
    from mcdenoise.io.atomic import sweep_stale_temporaries

    ours = [
        tmp_path / f"{TMP_PREFIX}{pid}@{host_tag()}~abc.exr"
        for pid in ("0", "9" * 30, "123456789012")
    ]
    for p in ours:
        p.write_bytes(b"x")
    assert sorted(sweep_stale_temporaries(tmp_path)) == sorted(ours)  # no such process here

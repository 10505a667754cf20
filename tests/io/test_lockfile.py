"""A lock file naming its holder (``mcdenoise/io/lockfile.py``): the heartbeat, a lock taken
over while held, half-written lock files. The refusals through the CLI are in
``tests/security/test_data_safety.py``."""

from __future__ import annotations

import json
import os
import time

import pytest

from mcdenoise.io.lockfile import LockError, LockFile, live_holder, read_holder


def test_the_holder_is_written_and_removed(tmp_path):
    path = tmp_path / "sub" / "run.lock"
    with LockFile(path, "a test", heartbeat=None) as lock:
        holder = read_holder(path)
        assert holder is not None and holder.pid == os.getpid() and holder.what == "a test"
        assert holder.token == lock.token
        with pytest.raises(LockError, match=f"process {os.getpid()}"):
            LockFile(path, "another", heartbeat=None).acquire()  # even from this process
    assert not path.exists()


def test_the_heartbeat_keeps_a_long_run_live(tmp_path):
    path = tmp_path / "run.lock"
    with LockFile(path, "a test", heartbeat=0.05):
        old = time.time() - 3600
        os.utime(path, (old, old))
        time.sleep(0.5)
        assert time.time() - path.stat().st_mtime < 60
        assert live_holder(path, stale_after=600) is not None


def test_a_lock_taken_over_is_noticed_and_not_removed(tmp_path):
    path = tmp_path / "run.lock"
    lock = LockFile(path, "a test", heartbeat=None)
    lock.acquire()
    other = {"host": "elsewhere", "pid": 7, "started": "t", "what": "a run", "token": "other"}
    path.write_text(json.dumps(other))  # it went silent too long; another process took over
    with pytest.raises(LockError, match="taken over by a run"):
        lock.check()
    lock.release()
    assert json.loads(path.read_text())["token"] == "other"  # the new holder's lock stays


def test_a_half_written_lock_is_live_for_a_moment_then_stale(tmp_path):
    path = tmp_path / "run.lock"
    path.write_text('{"host": "x", "pi')
    assert live_holder(path) is not None  # its writer may be writing it right now
    old = time.time() - 120
    os.utime(path, (old, old))
    assert live_holder(path) is None
    with LockFile(path, "a test", heartbeat=None):
        assert read_holder(path) is not None


def test_a_holder_written_by_someone_else_is_shown_on_one_line() -> None:
    """A lock file's fields are shown escaped and cut: a newline or a terminal escape in a
    hand-written (or hostile) lock file cannot break or rewrite the refusal's line."""
    from mcdenoise.io.lockfile import Holder

    h = Holder("host\n2", 7, "now\x1b[2J", "a run\r\nrm -rf " + "x" * 200, "t")
    text = h.describe()
    assert text.isprintable() and "\\n" in text and "\\x1b" in text
    assert len(text) < 80 * 3 + 60

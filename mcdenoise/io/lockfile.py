"""A lock file that names its holder, for folders that several processes (or hosts) may share.

``with LockFile(path, "experiment run"):`` creates ``path`` with ``O_CREAT | O_EXCL`` (atomic
on local file systems and on NFS v3 and later, so it works across hosts that share a folder),
writes the holder into it (host, PID, start time, what it does, a random token), and removes
it on exit, Ctrl-C included. While held, a background thread touches the file every
:data:`HEARTBEAT_SECONDS`.

A lock already there is refused in one line naming its holder (:class:`LockError`), unless
it is stale, and then it is taken over:

* its holder ran on this host and its PID no longer runs (a crash, SIGKILL), or
* it has not been touched for :data:`STALE_SECONDS` (its host crashed or lost the shared
  folder; a live holder touches it far more often than that).

Two processes taking over the same stale lock at the same instant could both believe they
hold it; :meth:`LockFile.check` (called by the holder between units of work) then finds the
other's token and raises, so at most the unit in progress is done twice.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import os
import secrets
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcdenoise.errors import McdenoiseError
from mcdenoise.io.atomic import host_tag, pid_alive

#: How often a holder touches its lock file.
HEARTBEAT_SECONDS = 30.0
#: A lock file untouched for this long is stale, whoever holds it.
STALE_SECONDS = 600.0
#: A lock file that cannot be parsed is one being written for at most this long.
_UNREADABLE_GRACE = 30.0


class LockError(McdenoiseError):
    """The lock is held by another live process (the message names it), or was lost."""


@dataclass(frozen=True)
class Holder:
    """Who holds a lock file: host, PID, start time (ISO 8601), what it does, its token."""

    host: str
    pid: int
    started: str
    what: str
    token: str

    def describe(self) -> str:
        """``"an experiment run (process 123 on host1, since 2026-01-01T10:00:00+00:00)"``.

        The fields come from a file another process (or a person) wrote: each is shown on one
        line, control characters escaped, at most 80 characters."""
        what, host, started = (_printable(x) for x in (self.what, self.host, self.started))
        return f"{what} (process {self.pid} on {host}, since {started})"


def _printable(text: str, limit: int = 80) -> str:
    """``text`` with control characters (newlines, terminal escapes) escaped, cut at ``limit``."""
    out = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    return out if len(out) <= limit else out[: limit - 3] + "..."


def read_holder(path: str | os.PathLike[str]) -> Holder | None:
    """The holder written in the lock file ``path``; ``None`` when absent or unreadable."""
    try:
        data: Any = json.loads(Path(path).read_text(encoding="utf-8"))
        return Holder(
            str(data["host"]),
            int(data["pid"]),
            str(data["started"]),
            str(data["what"]),
            str(data["token"]),
        )
    except (OSError, ValueError, KeyError, TypeError):
        return None


def live_holder(path: str | os.PathLike[str], stale_after: float = STALE_SECONDS) -> Holder | None:
    """The holder of ``path`` if the lock is live, ``None`` when there is no lock or it is
    stale (see the module docstring). A file being written (unparsable, younger than a few
    seconds) counts as live, held by an unknown process."""
    p = Path(path)
    try:
        age = time.time() - p.stat().st_mtime
    except OSError:
        return None
    holder = read_holder(p)
    if holder is None:
        if age > _UNREADABLE_GRACE:
            return None
        return Holder("?", 0, "just now", "a process starting", "")
    if age > stale_after:
        return None
    if holder.host == host_tag() and not pid_alive(holder.pid):
        return None
    return holder


class LockFile:
    """An exclusive lock file naming its holder; a context manager (see the module docstring).

    Args:
        path: the lock file (its folder is created).
        what: what the holder does, as the refusal will say it ("an experiment run").
        stale_after: seconds untouched after which another process takes the lock over.
        heartbeat: seconds between touches while held (``None``: no background thread).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        what: str,
        *,
        stale_after: float = STALE_SECONDS,
        heartbeat: float | None = HEARTBEAT_SECONDS,
    ) -> None:
        self.path = Path(path)
        self.what = what
        self.stale_after = stale_after
        self.heartbeat = heartbeat
        self.token = ""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def acquire(self) -> None:
        """Create the lock file, taking over a stale one.

        Raises:
            LockError: another live process holds it (one line naming that process).
        """
        self.path.parent.mkdir(parents=True, exist_ok=True)
        token = secrets.token_hex(8)
        started = _dt.datetime.now(_dt.UTC).astimezone().isoformat(timespec="seconds")
        record = {
            "host": host_tag(),
            "pid": os.getpid(),
            "started": started,
            "what": self.what,
            "token": token,
        }
        for _ in range(5):
            try:
                fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            except FileExistsError:
                holder = live_holder(self.path, self.stale_after)
                if holder is not None:
                    raise LockError(
                        f"{self.path.parent} is in use: {holder.describe()} holds {self.path}; "
                        "wait for it to finish (if that process is gone, delete the lock file)"
                    ) from None
                with contextlib.suppress(FileNotFoundError):
                    self.path.unlink()  # stale: take it over
                continue
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write(json.dumps(record) + "\n")
                f.flush()
                os.fsync(f.fileno())
            self.token = token
            self._start_heartbeat()
            return
        raise LockError(f"{self.path}: could not take the lock (it keeps changing hands)")

    def check(self) -> None:
        """Raise :class:`LockError` unless the lock file still holds this holder's token."""
        holder = read_holder(self.path)
        if not self.token or holder is None or holder.token != self.token:
            who = holder.describe() if holder is not None else "nobody"
            raise LockError(
                f"{self.path}: this run's lock was taken over by {who} (this process was "
                "stopped or lost the folder for too long); stopping here"
            )

    def release(self) -> None:
        """Stop the heartbeat and remove the lock file if it is still this holder's."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        holder = read_holder(self.path)
        if self.token and holder is not None and holder.token == self.token:
            with contextlib.suppress(OSError):
                self.path.unlink()
        self.token = ""

    def _start_heartbeat(self) -> None:
        if self.heartbeat is None:
            return
        self._stop.clear()
        self._thread = threading.Thread(
            target=self._beat, name=f"lock-heartbeat {self.path.name}", daemon=True
        )
        self._thread.start()

    def _beat(self) -> None:
        assert self.heartbeat is not None
        while not self._stop.wait(self.heartbeat):
            holder = read_holder(self.path)
            if holder is None or holder.token != self.token:
                return  # lost: check() says so to the holder
            with contextlib.suppress(OSError):
                os.utime(self.path)

    def __enter__(self) -> LockFile:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

"""Running another program safely: its environment, a child that dies with its parent
(``PR_SET_PDEATHSIG`` through ``setpriv`` or ``prctl``), a watcher that kills the whole process
group when mcdenoise goes away, and the sweep of folders that killed runs left behind. Used by
the external-command methods (:mod:`mcdenoise.methods.external`), which decide what to run.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping
from functools import cache
from pathlib import Path
from typing import Any

import torch


def command_env(env: Mapping[str, str] | None = None) -> dict[str, str]:
    """The command's environment: ours, with the thread count mcdenoise runs with (torch's,
    what ``--threads`` / an experiment's ``threads`` set) as ``MCDENOISE_THREADS`` and, unless
    already set, ``OMP_NUM_THREADS``, so a command that honours either uses as many threads
    as the in-process methods it is compared with."""
    out = dict(os.environ if env is None else env)
    threads = str(torch.get_num_threads())
    out["MCDENOISE_THREADS"] = threads
    out.setdefault("OMP_NUM_THREADS", threads)
    return out


def _with_parent() -> tuple[list[str], Callable[[], None] | None]:
    """How a command is started so that it dies with mcdenoise: ``(launcher, preexec_fn)``.

    On Linux the kernel sends ``SIGKILL`` to a process whose parent dies when the process
    asked for it (``prctl(PR_SET_PDEATHSIG)``, kept across ``exec``). util-linux's
    ``setpriv --pdeathsig KILL --`` asks, then runs the command in its place (same pid, same
    session): the launcher, when it works here (:func:`_setpriv`). Otherwise the request is
    made by a ``preexec_fn`` (:func:`_die_with_parent`), which makes Python ``fork`` the
    whole process instead of ``vfork``: 25-35 ms more per command in a process that holds
    torch (against ~2 ms, measured on 2 shared cores). Elsewhere: neither.
    """
    launcher = _setpriv()
    if launcher:
        return list(launcher), None
    return [], _die_with_parent()


@cache
def _setpriv() -> tuple[str, ...]:
    """``setpriv --pdeathsig KILL --`` when it is on PATH and takes the option (util-linux
    2.33 and later; tried once on ``true``), else ``()``."""
    setpriv, true = shutil.which("setpriv"), shutil.which("true")
    if not sys.platform.startswith("linux") or setpriv is None or true is None:
        return ()
    launcher = (setpriv, "--pdeathsig", "KILL", "--")
    try:
        done = subprocess.run(
            [*launcher, true], capture_output=True, timeout=VERSION_TIMEOUT, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return ()
    return launcher if done.returncode == 0 else ()


def _die_with_parent() -> Callable[[], None] | None:
    """Linux: the ``preexec_fn`` that makes the kernel send the command ``SIGKILL`` when the
    thread that started it ends, however it ends (``kill -9`` of mcdenoise included); it
    runs in the child between ``fork`` and ``exec``. ``None`` elsewhere (the process group
    still ends the command at a timeout or Ctrl-C, and :func:`sweep_stale_folders` its
    folder).

    ``prctl`` is looked up here, in the parent, so the child only makes the call (a child of
    a threaded process must not import or load anything before ``exec``). The signal is
    tied to the calling *thread*: :func:`run_command` waits for the command in the thread
    that started it. A parent that died before the call is noticed through ``getppid``.
    """
    prctl = _prctl()
    if prctl is None:
        return None
    parent = os.getpid()
    kill = int(signal.SIGKILL)

    def preexec() -> None:
        prctl(PR_SET_PDEATHSIG, kill, 0, 0, 0)
        if os.getppid() != parent:  # mcdenoise died before the line above took effect
            os._exit(137)

    return preexec


@cache
def _prctl() -> Any:
    """libc's ``prctl`` (Linux), or ``None``."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        fn = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):  # pragma: no cover - a libc without prctl
        return None
    fn.argtypes = [ctypes.c_int, *[ctypes.c_ulong] * 4]
    fn.restype = ctypes.c_int
    return fn


def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists on this machine (another user's counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except OSError:  # pragma: no cover - e.g. a pid out of range
        return False
    return True


def _stale_folders(root: Path, now: float) -> Iterator[Path]:
    """This user's command folders under ``root`` that no running command uses: the pid in
    the name (``mcdenoise-cmd-<pid>-xxxx``) is not a running process, or the name holds none
    (folders of older versions) and it is older than :data:`STALE_SECONDS`."""
    uid = os.getuid() if hasattr(os, "getuid") else None
    try:
        entries = list(os.scandir(root))
    except OSError:
        return
    for entry in entries:
        if not entry.name.startswith(FOLDER_PREFIX):
            continue
        try:
            st = entry.stat(follow_symlinks=False)
        except OSError:
            continue
        if not entry.is_dir(follow_symlinks=False) or (uid is not None and st.st_uid != uid):
            continue
        pid_text = entry.name[len(FOLDER_PREFIX) :].partition("-")[0]
        if pid_text.isdigit() and "-" in entry.name[len(FOLDER_PREFIX) :]:
            pid = int(pid_text)
            if pid == os.getpid() or _alive(pid):
                continue
        elif now - st.st_mtime < STALE_SECONDS:
            continue
        yield Path(entry.path)


def _kill_left_in(folder: Path) -> None:
    """Linux: ``SIGKILL`` to every process of this user still working in ``folder`` (its
    current directory inside it): what a killed command started of its own (a script's
    program), which the parent-death signal of the command does not reach. A process is
    found by its working directory, so no other process is touched whatever pids were
    reused."""
    proc = Path("/proc")
    if not proc.is_dir():
        return
    inside = os.path.realpath(folder)
    for entry in proc.iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            cwd = os.readlink(entry / "cwd")
        except OSError:  # gone, or another user's
            continue
        if cwd == inside or cwd.startswith(inside + os.sep):
            try:
                os.kill(int(entry.name), signal.SIGKILL)
            except OSError:
                pass


def sweep_stale_folders(root: str | os.PathLike[str] | None = None) -> list[Path]:
    """Remove the temporary folders of commands that no running mcdenoise process owns
    (:func:`_stale_folders`) from ``root`` (default: the temporary folder), after ending
    any process still working in one (:func:`_kill_left_in`); returns them. Errors (a
    folder removed meanwhile, another user's) are ignored."""
    base = Path(tempfile.gettempdir() if root is None else root)
    removed = []
    for folder in _stale_folders(base, time.time()):
        _kill_left_in(folder)
        try:
            shutil.rmtree(folder)
        except OSError:
            continue
        removed.append(folder)
    return removed


@cache
def _sweep_once() -> None:
    """:func:`sweep_stale_folders`, once per process (before its first command)."""
    sweep_stale_folders()


def _group_watcher(pgid: int) -> tuple[subprocess.Popen[bytes], int] | None:
    """A process that ends the command's whole process group if mcdenoise dies first.

    The parent-death signal (:func:`_with_parent`) reaches the command itself, not what the
    command started (a script's own program, a GPU binary under a wrapper), which would
    otherwise run on after a ``kill -9`` of mcdenoise. The watcher, a ``sh`` in a session of
    its own, blocks reading a pipe whose only writing end mcdenoise holds; the kernel closes
    that end when mcdenoise dies however it dies, the read returns, and the watcher sends
    ``SIGKILL`` to the group (the command runs in its own session, so the group is the
    command and everything it started that did not leave it). On a normal end
    :func:`_stop_watcher` kills the watcher before closing the pipe, so nothing is sent.
    ``None`` where there is no ``sh`` or no process groups (the command then still dies
    with mcdenoise; what it started may not). Costs one ``sh`` start and stop: 0.3 ms at best,
    4.5 ms median, in a process holding torch on 2 busy cores.
    """
    sh = shutil.which("sh")
    if sh is None or not hasattr(os, "killpg"):
        return None
    read_end, write_end = os.pipe()  # neither end is inherited by other children
    try:
        watcher = subprocess.Popen(
            [sh, "-c", 'read _ignored; kill -KILL "-$0" 2>/dev/null', str(pgid)],
            stdin=read_end,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,  # a Ctrl-C to mcdenoise's group does not end it first
        )
    except OSError:
        os.close(write_end)
        return None
    finally:
        os.close(read_end)
    return watcher, write_end


def _stop_watcher(watcher: tuple[subprocess.Popen[bytes], int] | None) -> None:
    """End the watcher of a command that finished (or was ended) while mcdenoise lives."""
    if watcher is None:
        return
    proc, write_end = watcher
    with contextlib.suppress(OSError):
        proc.kill()
    proc.wait()
    os.close(write_end)


def _kill(proc: subprocess.Popen[str]) -> None:
    """End the command and its children (its own session, POSIX), or the command alone."""
    try:
        if hasattr(os, "killpg"):
            os.killpg(proc.pid, signal.SIGKILL)
        else:  # pragma: no cover - Windows has no process groups of this kind
            proc.kill()
    except ProcessLookupError:
        pass


#: ``prctl`` option: the signal a process gets when its parent (thread) dies (linux/prctl.h).
PR_SET_PDEATHSIG = 1


#: Seconds after which a temporary folder without a recorded process is swept.
STALE_SECONDS = 3600.0


#: Prefix of a command's temporary folder; the pid of the mcdenoise process follows.
FOLDER_PREFIX = "mcdenoise-cmd-"


#: Seconds ``PROGRAM --version`` may take to be recorded.
VERSION_TIMEOUT = 2.0

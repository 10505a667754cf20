"""Safe file replacement: write a temporary file in the target folder, flush it to the disk,
check it, then ``os.replace`` it into place.

A reader (or a crash) therefore sees either the old file or the complete new one, never a
partial file, and no temporary file is left behind when the write fails or is interrupted
(``KeyboardInterrupt`` included). Every write, whatever library makes the bytes (OpenImageIO,
``torch.save``, matplotlib, plain text), goes through :func:`atomic_path`, which after the
writer has finished

1. ``fsync``\\ s the temporary file, so a full disk or an I/O error that the writer's own
   ``close()`` swallowed (OpenImageIO's returns true after a failed flush) is reported here;
2. runs the caller's check of the written file (an EXR is re-read down to its last chunk,
   :func:`mcdenoise.io.exr_layout.check_complete`);
3. renames it into place and ``fsync``\\ s the folder, so the new name survives a power loss.

When any step fails the temporary file is removed, the file at the final path is untouched,
and the error (:class:`~mcdenoise.errors.WriteError`) names the final path, says why, and how
much room is left when the disk is nearly full.

Temporary names carry the writer's PID and host (``.mcdenoise-tmp-<pid>@<host>~<random>.exr``).
A process killed outright (SIGKILL, power loss) cannot clean up; the next write into the same
folder removes the temporaries of *this* host's processes that no longer run, and any
temporary not modified for :data:`STALE_SECONDS`: another host's in-progress file on a shared
folder (``mcdenoise experiment --shard`` on a cluster) is never taken for an orphan.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import socket
import tempfile
import time
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path

from mcdenoise.errors import McdenoiseError, WriteError
from mcdenoise.io.exr_layout import check_complete
from mcdenoise.io.limits import format_bytes

#: Prefix of temporary files; ``.gitignore`` and folder scans skip names starting with it.
TMP_PREFIX = ".mcdenoise-tmp-"
#: A temporary file not modified for this long is an orphan, whoever wrote it.
STALE_SECONDS = 3600.0
#: Below this much free room, a failed write's message says how much is left.
_LOW_ROOM = 64 * 2**20

_TMP_NAME = re.compile(re.escape(TMP_PREFIX) + r"(\d+)@([A-Za-z0-9._-]*)~")


def host_tag() -> str:
    """This machine's host name as it appears in temporary names (``[A-Za-z0-9._-]``)."""
    return re.sub(r"[^A-Za-z0-9._-]", "_", socket.gethostname() or "unknown")[:64]


def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this host (a number no process can have: no)."""
    if pid == os.getpid():
        return True
    if pid <= 0:  # 0 and negative numbers name process groups, not a process
        return False
    try:
        os.kill(pid, 0)
    except PermissionError:  # exists, owned by someone else
        return True
    except (OSError, OverflowError):  # no such process, or a number beyond any PID
        return False
    return True


def _final_mode(final: Path) -> int:
    """Permissions for the new file: those of the file it replaces, else 0o666 minus umask
    (``mkstemp`` creates 0o600 files, which ``os.replace`` would otherwise keep)."""
    try:
        return final.stat().st_mode & 0o7777
    except OSError:
        mask = os.umask(0)
        os.umask(mask)
        return 0o666 & ~mask


def _is_stale(name: str, mtime: float, now: float) -> bool:
    """Whether the temporary ``name`` (last modified at ``mtime``) is an orphan."""
    if now - mtime > STALE_SECONDS:
        return True
    m = _TMP_NAME.match(name)
    return m is not None and m.group(2) == host_tag() and not pid_alive(int(m.group(1)))


def sweep_stale_temporaries(folder: str | os.PathLike[str]) -> list[Path]:
    """Remove the orphaned temporaries in ``folder`` (see the module docstring); return them.

    A name without a host (written by an older version) is removed only once stale by age.
    """
    removed: list[Path] = []
    now = time.time()
    with contextlib.suppress(OSError):
        for entry in os.scandir(folder):
            if not entry.name.startswith(TMP_PREFIX):
                continue
            with contextlib.suppress(OSError):
                if _is_stale(entry.name, entry.stat(follow_symlinks=False).st_mtime, now):
                    os.unlink(entry.path)
                    removed.append(Path(entry.path))
    return removed


def room_note(folder: str | os.PathLike[str]) -> str:
    """``"; only 12 KiB free on that disk"`` when the disk holding ``folder`` is nearly full,
    else ``""``: what a failed write's message adds."""
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        return ""
    if free >= _LOW_ROOM:
        return ""

    return f"; only {format_bytes(free)} free on that disk" if free else "; that disk is full"


def _fsync(path: str | os.PathLike[str], *, folder: bool = False) -> None:
    """Flush ``path`` (a file, or a folder's entries) to the disk; a folder that cannot be
    opened or synced (some file systems refuse) is skipped, a file's error is raised."""
    flags = os.O_RDONLY | (getattr(os, "O_DIRECTORY", 0) if folder else 0)
    try:
        fd = os.open(path, flags)
    except OSError:
        if folder:
            return
        raise
    try:
        os.fsync(fd)
    except OSError:
        if not folder:
            raise
    finally:
        os.close(fd)


def _ends_with(trailer: bytes, what: str) -> Callable[[Path], None]:
    """A check that a file ends with ``trailer`` (the last bytes every complete ``what`` has)."""

    def check(path: Path) -> None:
        size = path.stat().st_size
        with open(path, "rb") as f:
            f.seek(max(size - len(trailer), 0))
            if f.read() != trailer:
                raise OSError(0, f"the {what} written is incomplete ({size} bytes, no end marker)")

    return check


def _check_exr(path: Path) -> None:

    check_complete(path)


def _check_zip(path: Path) -> None:

    if not zipfile.is_zipfile(path):  # torch.save writes a zip archive; its directory is last
        raise OSError(0, f"the file written is incomplete ({path.stat().st_size} bytes)")


#: The check of a written file by its suffix, when the caller gives none: each reads a few
#: bytes (an EXR's headers, offset tables and last chunk header; a PNG's IEND chunk; a GIF's
#: trailer; a zip archive's directory), whatever the file's size.
DEFAULT_CHECKS: dict[str, Callable[[Path], None]] = {
    ".exr": _check_exr,
    ".png": _ends_with(b"\0\0\0\0IEND\xaeB`\x82", "PNG"),
    ".gif": _ends_with(b";", "GIF"),
    ".pt": _check_zip,
    ".pth": _check_zip,
}


def _write_error(final: Path, tmp: Path, err: OSError) -> WriteError:
    """``err`` (about the temporary file) as one line naming the final file."""
    why = err.strerror or " ".join(str(err).replace(str(tmp), str(final)).split())
    return WriteError(f"{final}: cannot write ({why}){room_note(final.parent)}")


@contextlib.contextmanager
def atomic_path(
    path: str | os.PathLike[str],
    *,
    verify: Callable[[Path], None] | None = None,
    sweep: bool = True,
) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; once the caller has written it, flush it to
    the disk, run ``verify(tmp)`` (which raises when the file is not what was meant to be
    written; default: the check of :data:`DEFAULT_CHECKS` for the suffix, if any), and
    replace ``path`` with it atomically.

    The temporary name keeps the final suffix (``.exr``, ``.json``) because some writers
    (OpenImageIO) choose the format from the extension.

    Raises:
        WriteError: the file could not be written, flushed or renamed (one line naming
            ``path``); an error of the caller's writer or of ``verify`` that is already a
            :class:`~mcdenoise.errors.McdenoiseError` is raised unchanged. Either way the
            temporary file is gone and ``path`` is as it was.

    ``sweep=False`` skips the sweep of the folder's orphaned temporaries
    (:func:`sweep_stale_temporaries`) for a batch that writes many files into one folder and
    sweeps it once first: a sweep before every write made n writes O(n²) (the 12 000 images
    of a 3000-output ``eval`` report).

    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> with atomic_path(d / "a.txt") as tmp:
    ...     _ = tmp.write_text("hello")
    >>> (d / "a.txt").read_text(), sorted(p.name for p in d.iterdir())
    ('hello', ['a.txt'])
    """
    final = Path(path)
    folder = final.parent if str(final.parent) else Path(".")
    if sweep:
        sweep_stale_temporaries(folder)
    try:
        fd, name = tempfile.mkstemp(
            prefix=f"{TMP_PREFIX}{os.getpid()}@{host_tag()}~", suffix=final.suffix, dir=folder
        )
    except OSError as err:
        raise _write_error(final, final, err) from None
    os.close(fd)
    tmp = Path(name)
    check = verify if verify is not None else DEFAULT_CHECKS.get(final.suffix.lower())
    try:
        try:
            yield tmp
            _fsync(tmp)
            if check is not None:
                check(tmp)
            os.chmod(tmp, _final_mode(final))
            os.replace(tmp, final)
        except McdenoiseError as err:  # the writer's or verify's: name the final file
            text, note = str(err).replace(str(tmp), str(final)), room_note(folder)
            if text == str(err) and not note:
                raise
            raise type(err)((text.rstrip(".") + note) if note else text) from None
        except OSError as err:
            raise _write_error(final, tmp, err) from None
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    _fsync(folder, folder=True)


def write_bytes_atomic(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically; a short write (a full disk) is an error."""

    def complete(tmp: Path) -> None:
        size = tmp.stat().st_size
        if size != len(data):
            raise OSError(0, f"{size} of {len(data)} bytes reached the disk")

    with atomic_path(path, verify=complete) as tmp:
        fd = os.open(tmp, os.O_WRONLY | os.O_TRUNC)
        try:
            view = memoryview(data)
            while view:
                n = os.write(fd, view)
                if n <= 0:
                    raise OSError(0, "the disk accepted no more bytes")
                view = view[n:]
        finally:
            os.close(fd)


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (:func:`write_bytes_atomic`)."""
    write_bytes_atomic(path, text.encode("utf-8"))

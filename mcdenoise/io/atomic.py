"""Atomic file replacement: write to a temporary name in the target folder, then ``os.replace``.

A reader (or a crash) therefore sees either the old file or the complete new one, never a
partial file, and no temporary file is left behind when the write fails or is interrupted
(``KeyboardInterrupt`` included). A process killed outright (SIGKILL, power loss) cannot clean
up; its temporary file carries its PID in the name (``.mcdenoise-tmp-<pid>-...``) and the next
atomic write into the same folder removes temporaries whose process no longer exists.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

#: Prefix of temporary files; ``.gitignore`` and folder scans skip names starting with it.
TMP_PREFIX = ".mcdenoise-tmp-"


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
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


def sweep_stale_temporaries(folder: str | os.PathLike[str]) -> list[Path]:
    """Remove temporaries in ``folder`` left by processes that no longer run; return them."""
    removed: list[Path] = []
    with contextlib.suppress(OSError):
        for entry in os.scandir(folder):
            if not entry.name.startswith(TMP_PREFIX):
                continue
            pid_text = entry.name[len(TMP_PREFIX) :].split("-", 1)[0]
            if pid_text.isdigit() and not _pid_alive(int(pid_text)):
                with contextlib.suppress(OSError):
                    os.unlink(entry.path)
                    removed.append(Path(entry.path))
    return removed


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success it replaces ``path`` atomically.

    The temporary name keeps the final suffix (``.exr``, ``.json``) because some writers
    (OpenImageIO) choose the format from the extension.

    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> with atomic_path(d / "a.txt") as tmp:
    ...     _ = tmp.write_text("hello")
    >>> (d / "a.txt").read_text(), sorted(p.name for p in d.iterdir())
    ('hello', ['a.txt'])
    """
    final = Path(path)
    folder = final.parent if str(final.parent) else Path(".")
    sweep_stale_temporaries(folder)
    fd, name = tempfile.mkstemp(
        prefix=f"{TMP_PREFIX}{os.getpid()}-", suffix=final.suffix, dir=folder
    )
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        os.chmod(tmp, _final_mode(final))
        os.replace(tmp, final)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")

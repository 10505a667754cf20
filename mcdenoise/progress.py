"""Progress of long stages: a tqdm bar on a terminal, a few plain lines in a log.

Every long loop of the library (render, denoise, train, ``mcdenoise experiment``) reports
through :func:`progress_bar`, the one place that decides how progress looks:

* ``progress=True`` (the default of the commands) and stderr a terminal: a tqdm bar on
  stderr (units done / total, the current item, time left);
* ``progress=True`` and stderr *not* a terminal (a log file, a pipe, CI): no carriage returns;
  one line when the stage starts (``denoise: 120 units ...``), at most one line a minute
  while it runs (``denoise: 40/120 units, cornell 8 spp nlm, about 2 min left``) and one
  line when it ends (``denoise: 120 units done in 12 s``);
* ``progress=False``: nothing.

``progress="bar"`` or ``"lines"`` forces one of the two forms. The object returned has the
part of tqdm's interface the library uses (``update``, ``set_postfix_str``, ``set_postfix``,
``write``, ``close``, iteration, a context manager), so the loops are written once.
"""

from __future__ import annotations

import io
import os
import shutil
import sys
import time
from collections.abc import Iterable, Iterator
from typing import IO, Any, Literal

Mode = bool | Literal["auto", "bar", "lines", "off"]

#: Seconds between two "still running" lines in a log.
LOG_INTERVAL = 60.0


def _stream() -> IO[str]:
    return sys.stderr


def resolve_mode(progress: Mode) -> str:
    """``"bar"``, ``"lines"`` or ``"off"`` for ``progress`` (``True``/``"auto"``: a bar when
    stderr is a terminal, else lines).

    >>> resolve_mode(False), resolve_mode("lines")
    ('off', 'lines')
    """
    if progress is False or progress == "off":
        return "off"
    if progress in ("bar", "lines"):
        return str(progress)
    if progress is True or progress == "auto":
        stream = _stream()
        try:
            return "bar" if stream.isatty() else "lines"
        except (AttributeError, ValueError):
            return "lines"
    raise ValueError(f"progress must be True, False, 'auto', 'bar', 'lines' or 'off': {progress!r}")


def format_seconds(seconds: float) -> str:
    """``12.3`` -> ``'12 s'``, ``150`` -> ``'2.5 min'``, ``7200`` -> ``'2.0 h'``.

    >>> format_seconds(0.42), format_seconds(150), format_seconds(7200)
    ('0.4 s', '2.5 min', '2.0 h')
    """
    if seconds < 10:
        return f"{seconds:.1f} s"
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


class LineProgress:
    """Progress as whole lines on stderr (for logs): start, at most one line every
    ``interval`` seconds, end."""

    def __init__(
        self,
        iterable: Iterable[Any] | None,
        *,
        total: int | None,
        desc: str,
        unit: str,
        initial: int = 0,
        interval: float | None = None,
    ) -> None:
        self.iterable = iterable
        if total is None and iterable is not None and hasattr(iterable, "__len__"):
            total = len(iterable)  # type: ignore[arg-type]
        self.total = total
        self.desc = desc
        self.unit = unit
        self.n = initial
        self._initial = initial
        self._postfix = ""
        self._interval = LOG_INTERVAL if interval is None else interval
        self._start = time.perf_counter()
        self._last = self._start
        self._closed = False
        self._emit(f"{self._what()} ...")

    def _units(self) -> str:
        unit = self.unit if self.unit.endswith("s") or self.total == 1 else f"{self.unit}s"
        return unit

    def _what(self) -> str:
        if self.total is None:
            return f"{self.desc}:"
        todo = self.total - self._initial
        if self._initial:
            return f"{self.desc}: {todo} of {self.total} {self._units()} left"
        return f"{self.desc}: {self.total} {self._units()}"

    def _emit(self, line: str) -> None:
        stream = _stream()
        stream.write(line + "\n")
        stream.flush()

    def __iter__(self) -> Iterator[Any]:
        assert self.iterable is not None
        try:
            for item in self.iterable:
                yield item
                self.update(1)
        finally:
            self.close()

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close(failed=exc[0] is not None)

    def update(self, n: int = 1) -> None:
        self.n += n
        now = time.perf_counter()
        if now - self._last >= self._interval and not self._closed:
            self._last = now
            self._emit(self._status(now))

    def _status(self, now: float) -> str:
        done = self.n - self._initial
        elapsed = now - self._start
        parts = [f"{self.n}/{self.total}" if self.total is not None else f"{self.n}"]
        text = f"{self.desc}: {parts[0]} {self._units()}"
        if self._postfix:
            text += f", {self._postfix}"
        if self.total is not None and done > 0:
            left = elapsed / done * (self.total - self.n)
            text += f", about {format_seconds(left)} left"
        return text

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        self._postfix = str(s)

    def set_postfix(self, ordered_dict: Any = None, refresh: bool = True, **kwargs: Any) -> None:
        items = dict(ordered_dict or {}, **kwargs)
        self._postfix = ", ".join(f"{k}={v}" for k, v in items.items())

    def set_description(self, desc: str | None = None, refresh: bool = True) -> None:
        self.desc = desc or ""

    def write(self, s: str) -> None:
        self._emit(s)

    def close(self, failed: bool = False) -> None:
        if self._closed:
            return
        self._closed = True
        seconds = format_seconds(time.perf_counter() - self._start)
        if failed or (self.total is not None and self.n < self.total):
            done = f"{self.n}/{self.total}" if self.total is not None else str(self.n)
            self._emit(f"{self.desc}: stopped after {done} {self._units()} ({seconds})")
        else:
            self._emit(f"{self.desc}: {self.n} {self._units()} done in {seconds}")


def progress_bar(
    iterable: Iterable[Any] | None = None,
    *,
    total: int | None = None,
    desc: str,
    unit: str = "it",
    progress: Mode = True,
    initial: int = 0,
    leave: bool = True,
) -> Any:
    """A progress reporter for one stage (see the module docstring for the forms).

    Args:
        iterable: iterate over it (the bar counts its items), or ``None`` and call ``update``.
        total: the number of units (default: ``len(iterable)``).
        desc: the stage's name (``"render"``, ``"denoise"``, ``"experiment"``, ...).
        unit: what is counted (``"image"``, ``"unit"``, ``"step"``).
        progress: ``True``/``"auto"``, ``"bar"``, ``"lines"``, or ``False``/``"off"``.
        initial: units already done (a resumed run).
        leave: keep the finished bar on the terminal.

    Returns:
        A tqdm bar (``"bar"``; disabled for ``"off"``) or a :class:`LineProgress`.
    """
    mode = resolve_mode(progress)
    if mode == "lines":
        return LineProgress(iterable, total=total, desc=desc, unit=unit, initial=initial)
    from tqdm import tqdm  # lazy: start-up of mcdenoise denoise

    stream = _stream()
    size = _zero_size_fallback(stream)
    return tqdm(
        iterable,
        total=total,
        desc=desc,
        unit=unit,
        initial=initial,
        leave=leave,
        file=stream,
        disable=mode == "off",
        ncols=size[0],
        nrows=size[1],
        dynamic_ncols=size[0] is None,
    )


def _zero_size_fallback(stream: IO[str]) -> tuple[int | None, int | None]:
    """``(columns, rows)`` for a terminal that reports a size of 0 (a pty without a size, e.g.
    under ``script`` or some CI runners), where tqdm would draw nothing; else ``(None, None)``
    (tqdm asks the terminal itself)."""
    try:
        size = os.get_terminal_size(stream.fileno())
    except (AttributeError, OSError, ValueError, io.UnsupportedOperation):
        return None, None
    if size.columns > 0 and size.lines > 0:
        return None, None
    fallback = shutil.get_terminal_size((100, 24))
    return (size.columns or fallback.columns or 100), (size.lines or fallback.lines or 24)


def write_line(text: str) -> None:
    """One message line on stderr that does not break a running bar (``tqdm.write``)."""
    from tqdm import tqdm  # lazy: start-up of mcdenoise denoise

    tqdm.write(text, file=_stream())

"""Timing of denoisers: warm-up runs excluded, the median of the timed repetitions.

A denoiser's first call on a new input pays for things the steady state does not (memory
allocation, lazy initialisation, OIDN device creation, thread-pool start-up), and machines
shared with other jobs add noise in both directions. So every input is denoised ``warmup``
times untimed, then ``repetitions`` times timed, and the *median* of the timed runs is
reported, next to every individual run, the device and the torch thread count (they decide the
number as much as the algorithm does).

The seconds of one run are the method's own wall time as measured by
:func:`mcdenoise.denoise.denoise` (``DenoiseResult.seconds``: the method only, no file I/O,
no sanitising, with a CUDA synchronisation around it on a GPU), except for external command
methods (:mod:`mcdenoise.methods.external`): theirs is the whole process (writing the inputs,
starting the program, its own loading and work, reading its output), since mcdenoise cannot
see inside another program. :func:`timing_clock` names which of the two a record's seconds
are (results.csv/json ``timing``), and the report marks the process times.
"""

from __future__ import annotations

import contextlib
import os
import platform
import statistics
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, TypeVar

import torch

from mcdenoise.errors import McdenoiseError
from mcdenoise.registry import get_method, is_command

T = TypeVar("T")

#: ``timing`` of a method timed in this process (the method's own work only).
IN_PROCESS = "in-process"
#: ``timing`` of an external command (the whole process, inputs and output files included).
PROCESS = "process"


def timing_clock(method: str) -> str | None:
    """What a record's denoise seconds measure for the registry method ``method``:
    :data:`PROCESS` for an external command, :data:`IN_PROCESS` otherwise, ``None`` for
    ``noisy`` (no denoiser) or a name the registry does not know.

    >>> timing_clock("noisy") is None, timing_clock("nlm")
    (True, 'in-process')
    """

    if method == "noisy":
        return None
    if is_command(method):  # a name read from a record builds no command
        return PROCESS
    try:
        m = get_method(method)
    except McdenoiseError:
        return None
    return PROCESS if "command" in m.defaults else IN_PROCESS


@dataclass(frozen=True)
class Timing:
    """The timed runs of one (method, input).

    Attributes:
        median: median of ``runs`` in seconds (the reported denoise time).
        runs: seconds of every timed run, in order.
        warmup: seconds of the untimed warm-up runs (recorded, never used).
        device: device the runs used (``"cpu"``, ``"cuda:0"``).
        threads: torch intra-op threads during the runs.
    """

    median: float
    runs: tuple[float, ...]
    warmup: tuple[float, ...] = ()
    device: str = "cpu"
    threads: int = field(default_factory=torch.get_num_threads)

    def to_dict(self) -> dict[str, Any]:
        return {
            "median": self.median,
            "runs": list(self.runs),
            "warmup": list(self.warmup),
            "device": self.device,
            "threads": self.threads,
        }


def time_runs(
    run: Callable[[], tuple[T, float, str]], *, repetitions: int, warmup: int = 1
) -> tuple[T, Timing]:
    """Call ``run`` ``warmup`` times untimed, then ``repetitions`` times; time the latter.

    Args:
        run: one denoising run; returns ``(result, seconds, device)`` where ``seconds`` is the
            run's own measurement (e.g. ``DenoiseResult.seconds``).
        repetitions: timed runs (>= 1); the median of their seconds is reported.
        warmup: untimed runs before them (>= 0).

    Returns:
        The result of the last run and the :class:`Timing`.

    >>> calls = iter([(0, 9.0, "cpu"), (1, 1.0, "cpu"), (2, 3.0, "cpu"), (3, 2.0, "cpu")])
    >>> result, t = time_runs(lambda: next(calls), repetitions=3, warmup=1)
    >>> result, t.median, t.runs, t.warmup
    (3, 2.0, (1.0, 3.0, 2.0), (9.0,))
    """
    if repetitions < 1:
        raise ValueError(f"repetitions must be >= 1, got {repetitions}")
    if warmup < 0:
        raise ValueError(f"warmup must be >= 0, got {warmup}")
    warm: list[float] = []
    device = "cpu"
    for _ in range(warmup):
        _, seconds, device = run()
        warm.append(float(seconds))
    runs: list[float] = []
    result: Any = None
    for _ in range(repetitions):
        result, seconds, device = run()
        runs.append(float(seconds))
    return result, Timing(
        median=float(statistics.median(runs)),
        runs=tuple(runs),
        warmup=tuple(warm),
        device=device,
        threads=torch.get_num_threads(),
    )


@contextlib.contextmanager
def torch_threads(threads: int | None) -> Iterator[int]:
    """Run the block with ``threads`` torch intra-op threads (``None``: leave as is); restore
    the previous count afterwards. Yields the count in effect."""
    previous = torch.get_num_threads()
    if threads is not None and threads != previous:
        torch.set_num_threads(int(threads))
    try:
        yield torch.get_num_threads()
    finally:
        if torch.get_num_threads() != previous:
            torch.set_num_threads(previous)


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), else what ``platform`` knows."""
    with contextlib.suppress(OSError):
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine() or "unknown"


def machine_info() -> dict[str, Any]:
    """Where the timings were taken: CPU model and count, torch threads, load average, GPU."""
    info: dict[str, Any] = {
        "cpu": cpu_model(),
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "platform": platform.platform(),
        "python": platform.python_version(),
    }
    with contextlib.suppress(OSError, AttributeError):
        info["load_average"] = [round(v, 2) for v in os.getloadavg()]
    if torch.cuda.is_available():
        info["cuda_device"] = torch.cuda.get_device_name(0)
    return info

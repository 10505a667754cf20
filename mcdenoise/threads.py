"""How many CPU threads a command computes with, and a warning when a method runs far too slow.

torch runs its CPU operators on an OpenMP thread pool (libgomp in the CPU wheels) with one
thread per core by default, and libgomp's waiting threads *spin* at every barrier (for about
300 000 iterations, ``GOMP_SPINCOUNT``; ``OMP_WAIT_POLICY``). When another process is busy on
the same cores, a spinning thread burns the time slice the thread it waits for needs, and every
parallel operator pays for it: on 2 shared cores with a 2-thread torch loop running beside it,
``kalantari-xbf`` on a 128×128 sample took 82 s instead of 0.3 s. Measured choices
are in ``docs/results/threads.md``; what this module does about it:

* :func:`set_wait_policy` bounds the spinning: ``GOMP_SPINCOUNT=10000`` (a waiting thread spins
  about 30 times less long, then sleeps) unless the user chose ``OMP_WAIT_POLICY`` or
  ``GOMP_SPINCOUNT``. Not ``PASSIVE``: measured here, sleeping at every barrier made two
  threads 3× slower than one on an idle machine (futex wake-ups in a VM), while a short spin
  keeps two threads' idle speed. It must run before libgomp starts, i.e. before ``import torch``
  in the process: the ``mcdenoise`` command calls it first thing; library users set the
  variable themselves.
* :func:`choose_threads` picks the thread count: an explicit request; else ``OMP_NUM_THREADS``
  when set; else ``auto``: the physical cores this process may use minus the other tasks
  running on them right now (``/proc/loadavg``), at least 1, so a busy machine gets one
  thread and an idle one all its cores. :func:`apply_threads` sets it (``torch.set_num_threads``;
  Mitsuba's Dr.Jit pool with :func:`set_render_threads`).
* :func:`check_speed` compares a method's seconds with its recorded one-thread speed
  (:attr:`~mcdenoise.method.Method.recorded_speed`, declared with each method, read through the
  registry) and logs one warning per method and process when a run is more than
  :data:`SLOW_FACTOR` times slower, naming the likely cause.

The thread count and the wait policy are recorded in every output's header
(``mcdenoise:threads``, ``mcdenoise:omp_wait_policy``) and in experiment records (``threads``).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Mapping, MutableMapping
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "SLOW_FACTOR",
    "ThreadChoice",
    "apply_threads",
    "auto_threads",
    "check_speed",
    "choose_threads",
    "expected_seconds",
    "other_running_tasks",
    "physical_cores",
    "set_render_threads",
    "set_wait_policy",
    "wait_policy",
]

log = logging.getLogger(__name__)

#: How much slower than :attr:`~mcdenoise.method.Method.recorded_speed` a run may be before :func:`check_speed` warns.
SLOW_FACTOR = 10.0
#: Runs shorter than this never warn (start-up noise on tiny images is not worth a message).
MIN_WARN_SECONDS = 1.0

_ENV_POLICY = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")


#: The spin count the command sets (libgomp's default: 300 000; 0 or PASSIVE: sleep at once).
SPIN_COUNT = "10000"


def set_wait_policy(env: MutableMapping[str, str] | None = None) -> str:
    """Set ``GOMP_SPINCOUNT`` to :data:`SPIN_COUNT` in ``env`` (default ``os.environ``) unless
    the user set ``OMP_WAIT_POLICY`` or ``GOMP_SPINCOUNT``; returns the policy in effect
    (:func:`wait_policy`).

    Takes effect only if called before libgomp starts (before ``import torch``).
    """
    env = os.environ if env is None else env
    if not any(env.get(k, "").strip() for k in _ENV_POLICY):
        env["GOMP_SPINCOUNT"] = SPIN_COUNT
    return wait_policy(env)


def wait_policy(env: Mapping[str, str] | None = None) -> str:
    """The OpenMP wait policy the environment asks for: ``PASSIVE``, ``ACTIVE``,
    ``GOMP_SPINCOUNT=N`` or ``default`` (libgomp spins a while, then sleeps)."""
    env = os.environ if env is None else env
    parts = []
    policy = env.get("OMP_WAIT_POLICY", "").strip()
    if policy:
        parts.append(policy.upper())
    spin = env.get("GOMP_SPINCOUNT", "").strip()
    if spin:
        parts.append(f"GOMP_SPINCOUNT={spin}")
    return ", ".join(parts) or "default"


def usable_cpus() -> int:
    """Logical CPUs this process may run on (its affinity mask, e.g. under ``taskset``)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def physical_cores(cpuinfo: str | os.PathLike[str] = "/proc/cpuinfo") -> int:
    """Physical cores among the CPUs this process may use (hyper-threads counted once);
    the usable logical CPUs where ``/proc/cpuinfo`` says nothing about cores."""
    usable = usable_cpus()
    try:
        text = Path(cpuinfo).read_text()
    except OSError:
        return usable
    try:
        allowed: set[int] | None = set(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        allowed = None
    cores: set[tuple[str, str]] = set()
    for block in text.split("\n\n"):
        fields = dict(
            (k.strip(), v.strip()) for k, _, v in (ln.partition(":") for ln in block.splitlines())
        )
        if "processor" not in fields or "core id" not in fields:
            continue
        if allowed is not None and int(fields["processor"]) not in allowed:
            continue
        cores.add((fields.get("physical id", "0"), fields["core id"]))
    return min(usable, len(cores)) if cores else usable


def other_running_tasks(
    samples: int = 3, interval: float = 0.005, loadavg: str | os.PathLike[str] = "/proc/loadavg"
) -> int | None:
    """Tasks (threads) running or ready to run right now besides this one: the fourth field of
    ``/proc/loadavg`` minus 1, the least of ``samples`` readings ``interval`` seconds apart (a
    short-lived process does not count, a busy one does); ``None`` without ``/proc/loadavg``."""

    seen = []
    for i in range(max(1, samples)):
        if i:
            time.sleep(interval)
        try:
            running = Path(loadavg).read_text().split()[3].split("/")[0]
            seen.append(max(0, int(running) - 1))
        except (OSError, IndexError, ValueError):
            return None
    return min(seen)


def auto_threads() -> tuple[int, str]:
    """``(threads, why)``: the physical cores not busy with other tasks right now, at least 1."""
    cores = physical_cores()
    others = other_running_tasks()
    if others is None:
        return cores, f"auto: {cores} physical core(s), load unknown"
    free = max(1, min(cores, cores - others))
    return free, f"auto: {free} of {cores} physical core(s) free ({others} other task(s) running)"


@dataclass(frozen=True)
class ThreadChoice:
    """A thread count and how it was chosen (``--threads``, ``OMP_NUM_THREADS`` or ``auto``)."""

    threads: int
    source: str
    wait_policy: str

    def describe(self) -> str:
        return f"{self.threads} thread(s) ({self.source}; OpenMP wait policy {self.wait_policy})"


def choose_threads(
    requested: int | None = None, env: Mapping[str, str] | None = None
) -> ThreadChoice:
    """The thread count to use: ``requested`` (``--threads N``) if given; else a valid
    ``OMP_NUM_THREADS`` of the environment; else :func:`auto_threads`."""
    env = os.environ if env is None else env
    policy = wait_policy(env)
    if requested is not None:
        if requested < 1:
            raise ValueError(f"threads must be >= 1, not {requested}")
        return ThreadChoice(int(requested), "--threads", policy)
    omp = env.get("OMP_NUM_THREADS", "").strip().split(",")[0]
    if omp.isdigit() and int(omp) >= 1:
        return ThreadChoice(int(omp), "OMP_NUM_THREADS", policy)
    threads, why = auto_threads()
    return ThreadChoice(threads, why, policy)


def apply_threads(choice: ThreadChoice | int) -> int:
    """Set torch's intra-op thread count (a global torch setting); returns it."""
    import torch  # lazy: start-up without torch

    n = choice.threads if isinstance(choice, ThreadChoice) else int(choice)
    if torch.get_num_threads() != n:
        torch.set_num_threads(n)
    return torch.get_num_threads()


def set_render_threads(threads: int) -> bool:
    """Set the thread count of Mitsuba's CPU backend (Dr.Jit's pool; the calling thread counts
    as one); ``False`` when Dr.Jit is not installed."""
    try:
        import drjit  # lazy: optional, see except
    except ImportError:
        return False
    drjit.set_thread_count(int(threads))
    return True


# --- a method far slower than its recorded speed ----------------------------------------------

_warned: set[str] = set()  # methods already warned about in this process (one message each)


def expected_seconds(method: str, pixels: int) -> float | None:
    """The recorded one-thread idle seconds of ``method`` (a speed name,
    :meth:`~mcdenoise.method.Method.speed_name`) on a frame of ``pixels`` pixels; ``None``
    for a method without a record."""
    from mcdenoise.registry import recorded_speed  # lazy: torch; this module runs before it

    speed = recorded_speed(method)
    if speed is None:
        return None
    fixed, per_mp = speed
    return fixed + per_mp * pixels / 1e6


def check_speed(
    method: str, seconds: float, pixels: int, device: str = "cpu", threads: int | None = None
) -> str | None:
    """Warn (logger ``mcdenoise.threads``, once per method and process) when ``method`` took
    more than :data:`SLOW_FACTOR` times its recorded speed on the CPU; returns the message
    when it warned."""
    if device != "cpu" or method in _warned or seconds < MIN_WARN_SECONDS:
        return None
    expected = expected_seconds(method, pixels)
    if expected is None or seconds <= SLOW_FACTOR * expected:
        return None
    if threads is None:
        import torch  # lazy: start-up without torch

        threads = torch.get_num_threads()
    _warned.add(method)
    hint = (
        "try --threads 1 (or set OMP_NUM_THREADS=1)"
        if threads > 1
        else "it already runs on one thread; the machine is probably overloaded"
    )
    message = (
        f"method {method} took {seconds:.2f} s, {seconds / expected:.0f}x its recorded speed "
        f"({expected:.2f} s for {pixels / 1e6:.3g} megapixels on one idle thread): another "
        f"process is probably busy on the cores ({threads} torch thread(s) here); {hint}"
    )
    log.warning(message)
    return message

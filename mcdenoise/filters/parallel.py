"""Parallel work over tiles and row bands, with the caller's thread count.

The filters' inner loops run many small operations (one per window offset on a 256² tile);
letting torch split each of them over the cores (intra-op parallelism) costs one
synchronisation per operation, and on a loaded machine, where a core is often taken by another
process, that made the filters up to 10x slower with 2 threads than with 1
(``docs/results/kalantari.md``, "4K"). Here the *tiles* (or row bands) are shared by worker
threads instead, each running its operations single-threaded: every tile computes exactly what
it computes alone, so results do not depend on the number of threads.

* :func:`parallel_map` -- ``[fn(x) for x in items]`` on ``torch.get_num_threads()`` workers (on
  the CPU, without autograd; serial otherwise);
* :func:`single_threaded_ops` -- a block in which torch runs operations on one thread while
  :func:`parallel_map` keeps the caller's count of workers (the methods wrap a whole pipeline in
  it, so the whole-image operations between the parallel parts do not synchronise either).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from contextvars import ContextVar
from typing import TypeVar

import torch
from torch import Tensor

T = TypeVar("T")
R = TypeVar("R")

#: Workers of :func:`parallel_map` inside :func:`single_threaded_ops` (1: not inside).
_WORKERS: ContextVar[int] = ContextVar("mcdenoise_filter_workers", default=1)


def workers() -> int:
    """How many workers :func:`parallel_map` would use here."""
    return max(torch.get_num_threads(), _WORKERS.get())


@contextmanager
def single_threaded_ops() -> Iterator[int]:
    """Run the block with torch's intra-op threads set to 1; :func:`parallel_map` inside it
    still uses the caller's ``torch.get_num_threads()`` workers. Yields that count; restores the
    thread count on exit. Nested use is a no-op."""
    n = workers()
    if n <= 1 or _WORKERS.get() > 1:
        yield n
        return
    torch.set_num_threads(1)
    token = _WORKERS.set(n)
    try:
        yield n
    finally:
        _WORKERS.reset(token)
        torch.set_num_threads(n)


def parallel_map(fn: Callable[[T], R], items: Iterable[T], like: Tensor | None = None) -> list[R]:
    """``[fn(x) for x in items]``, the calls shared by :func:`workers` threads.

    Parallel only where it cannot change anything: more than one item and worker, autograd
    disabled (each worker then runs under ``torch.no_grad()``, and in inference mode when the
    caller is), and ``like`` (the data's tensor, if given) on the CPU. Operations run
    single-threaded meanwhile (:func:`single_threaded_ops`). An exception in a call is raised
    here (the first one in ``items`` order).
    """
    todo = list(items)
    n = min(workers(), len(todo))
    cpu = like is None or like.device.type == "cpu"
    if n <= 1 or not cpu or torch.is_grad_enabled():
        return [fn(x) for x in todo]
    inference = torch.is_inference_mode_enabled()

    def call(x: T) -> R:
        with torch.no_grad(), torch.inference_mode(inference):
            return fn(x)

    with single_threaded_ops(), ThreadPoolExecutor(n) as pool:
        futures = [pool.submit(call, x) for x in todo]
        return [f.result() for f in futures]


__all__ = ["parallel_map", "single_threaded_ops", "workers"]

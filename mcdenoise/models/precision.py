"""Inference precision of a network's convolution trunk (``-p precision=auto|fp32|bf16``).

The trunk of ``kpcn`` (encoder and U-Net, :meth:`~mcdenoise.models.kpcn.KpcnModel.features`)
is most of the network's time, and on a CPU with native bfloat16 arithmetic (AVX-512 BF16 or
AMX, ``torch.ops.mkldnn._is_mkldnn_bf16_supported``) oneDNN runs its convolutions in bfloat16
1.66× faster than in float32 (0.93 s against 0.56 s at 1 MP, 2 threads). Only the trunk runs
under ``torch.autocast``: its features are cast back to float32 before the kernel heads, so
the softmax, the kernel application, the compositor and the remodulation stay float32 (HDR
sums overflow half precision, and a kernel weight needs more than bfloat16's 8 significant
bits to keep energy).

``auto`` (the methods' default) is ``bf16`` where the device does bfloat16 natively (such a CPU,
or a CUDA device that reports bf16 support) and ``fp32`` elsewhere: emulated bfloat16 is slower
than float32. Measured on the held-out, hand-written textured and out-of-distribution renders
(``benchmarks/bench_precision.py``, ``docs/results/speed.md``): relMSE moves by ≤ 0.25 % in
geometric mean and 1.3 % on the worst image, against a tolerance of 0.5 % of the mean.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch

from mcdenoise.errors import InputError

#: Values of the ``precision`` parameter.
PRECISIONS = ("auto", "fp32", "bf16")


def native_bf16(device: torch.device | str) -> bool:
    """Whether ``device`` computes bfloat16 convolutions natively (not emulated)."""
    dev = torch.device(device)
    if dev.type == "cuda":
        return bool(torch.cuda.is_available() and torch.cuda.is_bf16_supported())
    if dev.type != "cpu" or not torch.backends.mkldnn.is_available():
        return False
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):  # an old or stripped build: do not guess
        return False


def resolve_precision(precision: str, device: torch.device | str) -> str:
    """``fp32`` or ``bf16``: ``auto`` resolved for ``device``.

    Raises:
        InputError: an unknown value.
    """
    if precision not in PRECISIONS:
        raise InputError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if precision == "auto":
        return "bf16" if native_bf16(device) else "fp32"
    return precision


@contextlib.contextmanager
def trunk_autocast(precision: str, device: torch.device | str) -> Iterator[None]:
    """``torch.autocast`` to bfloat16 on ``device`` when ``precision`` is ``bf16``; a no-op
    for ``fp32``."""
    if precision == "bf16":
        with torch.autocast(torch.device(device).type, dtype=torch.bfloat16):
            yield
    else:
        yield


__all__ = ["PRECISIONS", "native_bf16", "resolve_precision", "trunk_autocast"]

"""Record the outputs of every shipped method on ``data/samples`` (the golden file).

Run from the repository root, on the code whose outputs are to be kept::

    .venv/bin/python tests/methods/make_golden.py tests/methods/golden_outputs.npz

only when a method's output is meant to change (say which and why in the commit), never to
make another CPU pass (``docs/development.md``, "Golden outputs"). It keeps a fixed subset of
each output's pixels (every 17th pixel in raster order plus the whole border) so the file
stays small; ``test_golden_outputs.py`` recomputes them and compares within a tolerance
derived from float32 rounding across instruction sets (2.1e-4 of ``|value| + mean |value|``,
see there). Methods run on the CPU with one thread.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "data" / "samples"
METHODS = ("nlm", "cross-bilateral", "kalantari-xbf", "kalantari-nlm", "kpcn")
#: Parameters the golden outputs are recorded and compared with: ``kpcn``'s trunk in float32
#: (its default ``precision=auto`` is bfloat16 on a CPU that has it natively, a rounding no
#: float32 tolerance covers; ``tests/models/test_precision.py`` bounds what it changes).
PARAMS: dict[str, dict[str, str]] = {"kpcn": {"precision": "fp32"}}


def pixel_index(h: int, w: int) -> np.ndarray:
    """Flat indices kept per output: every 17th pixel and the whole border."""
    flat = np.arange(h * w)
    y, x = flat // w, flat % w
    keep = (flat % 17 == 0) | (y == 0) | (y == h - 1) | (x == 0) | (x == w - 1)
    return flat[keep]


def sample_files() -> list[Path]:
    return sorted(SAMPLES.glob("*_spp*.exr"))


def main(out: str) -> None:
    from mcdenoise.denoise import denoise
    from mcdenoise.io import load_buffers

    torch.set_num_threads(1)
    arrays: dict[str, np.ndarray] = {}
    for path in sample_files():
        buffers = load_buffers(path)
        for name in METHODS:
            img = denoise(buffers, name, params=PARAMS.get(name), device="cpu").image.numpy()
            idx = pixel_index(*img.shape[1:])
            arrays[f"{path.stem}/{name}"] = img.reshape(3, -1)[:, idx].astype(np.float32)
            print(path.stem, name, float(img.mean()), file=sys.stderr)
    np.savez_compressed(out, **arrays)


if __name__ == "__main__":
    main(sys.argv[1])

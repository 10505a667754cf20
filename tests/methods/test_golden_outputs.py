"""Every shipped method's output on ``data/samples`` equals the recorded one within 1e-6.

The golden file was written by ``make_golden.py`` (see there) on the code before the redesign
step of issue 19; a change that moves code around must not change what any method computes.
Re-record it only on purpose, when a method's output is meant to change, and say why in the
commit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from make_golden import METHODS, pixel_index, sample_files

GOLDEN = Path(__file__).with_name("golden_outputs.npz")


@pytest.fixture(scope="module")
def golden() -> dict[str, np.ndarray]:
    with np.load(GOLDEN) as f:
        return {k: f[k] for k in f.files}


def test_golden_covers_every_sample_and_method(golden):
    expected = {f"{p.stem}/{m}" for p in sample_files() for m in METHODS}
    assert expected and set(golden) == expected


@pytest.mark.parametrize("path", sample_files(), ids=lambda p: p.stem)
def test_outputs_unchanged(path, golden):
    from mcdenoise.denoise import denoise
    from mcdenoise.io import load_buffers

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        buffers = load_buffers(path)
        for name in METHODS:
            img = denoise(buffers, name, device="cpu").image.numpy()
            got = img.reshape(3, -1)[:, pixel_index(*img.shape[1:])]
            want = golden[f"{path.stem}/{name}"]
            np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6, err_msg=name)
    finally:
        torch.set_num_threads(threads)

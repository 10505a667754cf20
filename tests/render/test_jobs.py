"""Tests of ``mcdenoise.render.jobs``: seeds and the passes of the progressive levels (no
Mitsuba needed); job ids are tested with rendering in ``test_generate.py``."""

from __future__ import annotations

import numpy as np
import pytest

from mcdenoise.render.jobs import (
    frame_seed,
    image_seed,
    level_part,
    level_passes,
    noisy_seed,
    reference_seed,
    split_passes,
)


@pytest.mark.parametrize(
    ("levels", "pass_spp"), [((4, 16, 64), 128), ((1, 2, 300), 128), ((5,), 2), ((7, 1000), 100)]
)
def test_progressive_passes_cover_each_increment_once(levels, pass_spp) -> None:
    passes = level_passes(levels, pass_spp)
    assert len(passes) == len(levels)
    assert np.cumsum([sum(p) for p in passes]).tolist() == list(levels)
    assert all(1 <= n <= pass_spp for p in passes for n in p)


def test_noisy_and_reference_seeds_are_distinct_and_disjoint() -> None:
    s = image_seed(0, "cornell")
    n_noisy = sum(len(p) for p in level_passes((4, 16, 64, 1024), 128))
    n_ref = len(split_passes(4096, 128))
    noisy = {noisy_seed(s, k) for k in range(n_noisy)}
    ref = {reference_seed(s, k) for k in range(n_ref)}
    assert len(noisy) == n_noisy and len(ref) == n_ref and not noisy & ref
    assert all(0 <= v < 2**32 for v in noisy | ref)
    # Image seeds depend on the base seed and the id, not on the position in the job list.
    assert image_seed(0, "a") == image_seed(0, "a") != image_seed(1, "a") != image_seed(0, "b")


def test_frame_seeds_differ_between_frames_and_from_the_sequence_seed() -> None:
    s = image_seed(0, "seq")
    seeds = [frame_seed(s, f) for f in range(8)]
    assert len(set(seeds)) == 8 and s not in seeds
    assert level_part(16) == "spp16"

"""The Kalantari features computed a band of rows at a time (prep.kalantari.item_features, what
inference uses to avoid an F x H x W tensor) equal the whole image's, bit for bit."""

from __future__ import annotations

import pytest
import torch

from mcdenoise.io import load_buffers
from mcdenoise.methods.kalantari import denoise_kalantari, model_for
from mcdenoise.prep.kalantari import FEATURE_HALO, item_features, prepare_for_model


@pytest.mark.parametrize("kind", ["xbf", "nlm"])
def test_bands_equal_the_whole_image(samples_dir, kind: str) -> None:
    b = load_buffers(samples_dir / "cornell_spp4.exr")
    m = model_for(kind, b, "shipped")
    whole = prepare_for_model(m.card, b)
    item = prepare_for_model(m.card, b, features=False)
    assert "features" not in item
    rows = item_features(item, b.spp, regional=m.card.regional)
    h = b.shape[0]
    assert FEATURE_HALO < h  # the bands below really cut the context
    for y0, y1 in [(0, h), (0, 1), (5, 40), (h - 3, h), (60, 61)]:
        assert torch.equal(rows(y0, y1)[0], whole["features"][:, y0:y1]), (y0, y1)
    with pytest.raises(ValueError):
        rows(10, 10)


def test_streamed_denoise_equals_the_stored_features(samples_dir) -> None:
    b = load_buffers(samples_dir / "cornell_spp4.exr")
    m = model_for("xbf", b, "shipped")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # the MLP's rounding depends on the thread count
    try:
        stored = m.denoise_item(prepare_for_model(m.card, b), chunk_rows=32)
    finally:
        torch.set_num_threads(threads)
    # denoise_kalantari runs its operations single-threaded whatever the count
    assert torch.equal(denoise_kalantari(m, b, chunk_rows=40), stored)

"""Tests for mcdenoise/eval/preview.py: crop choice and overview thumbnails."""

from __future__ import annotations

import numpy as np

from mcdenoise.eval import preview as P


def test_small_images_are_shown_whole():
    assert P.choose_crop(np.zeros((3, 1, 1))) == (0, 0, 1, 1)
    assert P.choose_crop(np.zeros((3, 256, 200))) == (0, 0, 256, 200)


def test_crop_goes_where_the_detail_is():
    img = np.full((3, 600, 700), 0.3)
    yy, xx = np.mgrid[0:120, 0:100]
    img[:, 400:520, 500:600] = 0.3 + 0.25 * ((yy // 4 + xx // 4) % 2)  # a checkerboard
    y0, x0, h, w = P.choose_crop(img, exposure=1.0, size=256)
    assert (h, w) == (256, 256)
    assert y0 <= 400 and y0 + h >= 520 and x0 <= 500 and x0 + w >= 600
    assert 0 <= y0 <= 600 - 256 and 0 <= x0 <= 700 - 256


def test_crop_of_a_long_thin_image_keeps_its_short_side():
    img = np.random.default_rng(0).random((3, 40, 1000))
    y0, x0, h, w = P.choose_crop(img, size=256)
    assert (y0, h, w) == (0, 40, 256) and 0 <= x0 <= 1000 - 256
    assert P.crop(img, (y0, x0, h, w)).shape == (3, 40, 256)


def test_overview_downscales_by_box_average():
    img = np.arange(3 * 600 * 300, dtype=np.float64).reshape(3, 600, 300)
    small, factor = P.overview(img, max_side=256)
    assert factor == 3 and small.shape == (3, 200, 100)
    assert small[0, 0, 0] == np.float32(img[0, :3, :3].mean())
    tiny, f1 = P.overview(np.ones((3, 10, 10)))
    assert f1 == 1 and tiny.shape == (3, 10, 10)

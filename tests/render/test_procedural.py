"""Procedural images (mcdenoise/render/procedural.py): seeded value noise, gradient sky."""

from __future__ import annotations

import numpy as np
import pytest

from mcdenoise.render.procedural import noise_image, sky_image, value_noise


def test_value_noise_is_deterministic_tileable_and_in_range():
    n = value_noise(5)
    assert n.dtype == np.float32 and n.min() == 0.0 and n.max() == 1.0
    np.testing.assert_array_equal(n, value_noise(5))
    assert not np.array_equal(n, value_noise(6))
    # seamless: the jump across the wrap is no larger than between neighbours inside
    inner = np.abs(np.diff(n, axis=1)).max()
    assert np.abs(n[:, 0] - n[:, -1]).max() <= 1.5 * inner
    assert np.abs(n[0] - n[-1]).max() <= 1.5 * np.abs(np.diff(n, axis=0)).max()


def test_noise_image_blends_the_two_colours():
    img = noise_image((0.1, 0.2, 0.3), (0.5, 0.2, 0.9), seed=2, size=64)
    assert img.shape == (64, 64, 3) and img.dtype == np.float32
    np.testing.assert_allclose(img.min(axis=(0, 1)), [0.1, 0.2, 0.3], atol=1e-6)
    np.testing.assert_allclose(img.max(axis=(0, 1)), [0.5, 0.2, 0.9], atol=1e-6)


@pytest.mark.parametrize("bad", [{"size": 1}, {"cells": 0}, {"octaves": 0}])
def test_value_noise_rejects_degenerate_sizes(bad):
    with pytest.raises(ValueError):
        value_noise(0, **bad)


def test_sky_is_blue_above_bright_at_the_horizon_dark_below_and_constant_per_row():
    sky = sky_image(16, 9)
    assert sky.shape == (9, 16, 3) and sky.dtype == np.float32
    assert (sky == sky[:, :1]).all()  # no azimuthal variation
    lum = sky[:, 0].sum(-1)
    zenith, horizon, nadir = lum[0], lum[4], lum[-1]
    assert horizon > zenith > 2 * nadir
    assert sky[0, 0, 2] > sky[0, 0, 0]  # blue zenith
    assert (sky >= 0).all()

"""Tests for mcdenoise/eval/tonemap.py: sRGB curve, exposure, false colour."""

from __future__ import annotations

import numpy as np
import pytest

from mcdenoise.eval import tonemap as T


def test_srgb_encode_known_points_and_continuity():
    x = np.array([0.0, 0.0031308, 0.18, 0.5, 1.0])
    # IEC 61966-2-1 values (0.18 -> 0.46135 is the usual "middle grey is 46 %")
    expected = [0.0, 12.92 * 0.0031308, 0.46135612, 0.73535698, 1.0]
    assert T.srgb_encode(x) == pytest.approx(expected, abs=1e-7)
    # the linear and power pieces meet at the threshold
    below, above = T.srgb_encode(np.array([0.0031308 - 1e-9, 0.0031308 + 1e-9]))
    assert abs(above - below) < 1e-6
    ramp = T.srgb_encode(np.linspace(0, 1, 1001))
    assert np.all(np.diff(ramp) > 0)


def test_to_srgb_clamps_and_applies_exposure():
    x = np.array([[[-1.0, 0.5, 2.0, np.inf]]]).repeat(3, axis=0)
    y = T.to_srgb(x)
    assert y[0, 0].tolist() == pytest.approx([0.0, 0.73535698, 1.0, 1.0])
    assert T.to_srgb(x, exposure=2.0)[0, 0, 1] == pytest.approx(1.0)
    assert x[0, 0, 0] == -1.0  # input untouched


def test_auto_exposure():
    assert T.auto_exposure(np.full((3, 4, 4), 0.36)) == pytest.approx(0.5)
    assert T.auto_exposure(np.zeros((3, 4, 4))) == 1.0
    assert T.auto_exposure(np.full((3, 2, 2), np.nan)) == 1.0
    # scaling the scene by k scales the exposure by 1/k (same picture)
    rng = np.random.default_rng(0)
    img = rng.gamma(2.0, 0.3, size=(3, 16, 16))
    assert T.auto_exposure(10 * img) == pytest.approx(T.auto_exposure(img) / 10, rel=1e-9)
    # a few very bright pixels do not black out the rest: the log-average ignores them mostly
    lamp = img.copy()
    lamp[:, :2, :2] = 1e4
    assert T.auto_exposure(lamp) > 0.2 * T.auto_exposure(img)


def test_display_marks_nonfinite_pixels_magenta():
    x = np.full((3, 2, 2), 0.5)
    x[1, 0, 1] = np.nan
    x[0, 1, 0] = np.inf
    d = T.display(x, 1.0)
    assert d[:, 0, 1].tolist() == list(T.NONFINITE_RGB)
    assert d[:, 1, 0].tolist() == list(T.NONFINITE_RGB)
    assert np.all((d >= 0) & (d <= 1))


def test_false_color_ends_order_and_nonfinite():
    v = np.array([[1e-5, 1e-4, 1e-2, 1.0, 10.0, np.nan]])
    rgb = T.false_color(v, 1e-4, 1.0)
    assert rgb.shape == (3, 1, 6)
    np.testing.assert_allclose(rgb[:, 0, 0], T._INFERNO[0])  # clamped below lo
    np.testing.assert_allclose(rgb[:, 0, 1], T._INFERNO[0])
    np.testing.assert_allclose(rgb[:, 0, 3], T._INFERNO[-1])
    np.testing.assert_allclose(rgb[:, 0, 4], T._INFERNO[-1])  # clamped above hi
    np.testing.assert_allclose(rgb[:, 0, 5], T.NONFINITE_RGB)
    # brightness grows with the error along the whole scale
    ramp = T.false_color(np.logspace(-4, 0, 50)[None, :], 1e-4, 1.0)
    lum = T.luminance(ramp)[0]
    assert np.all(np.diff(lum) > 0)
    with pytest.raises(ValueError):
        T.false_color(v, 0.0, 1.0)  # log scale needs lo > 0


def test_colorbar_and_uint8():
    bar = T.colorbar(64, 4)
    assert bar.shape == (3, 4, 64)
    u = T.to_uint8(bar)
    assert u.shape == (4, 64, 3) and u.dtype == np.uint8
    assert u[0, 0].tolist() == np.round(T._INFERNO[0] * 255).astype(int).tolist()

"""Small draws shared by the random-scene modules: weighted choices, colours, light tints,
and the rounding that keeps specs compact."""

from __future__ import annotations

import colorsys
from collections.abc import Mapping, Sequence

import numpy as np

from mcdenoise.render.random_scenes.distribution import Lights, Materials, U

UP = np.array([0.0, 1.0, 0.0])
#: Rec. 709 luminance weights of linear RGB.
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def choose(rng: np.random.Generator, weights: Mapping[str, float]) -> str:
    """A key of ``weights`` drawn with probabilities proportional to its values."""
    keys = list(weights)
    p = np.asarray([weights[k] for k in keys], dtype=np.float64)
    return keys[int(rng.choice(len(keys), p=p / p.sum()))]


def rounded(x: float, nd: int = 4) -> float:
    """Round for a compact, readable spec (and manifest)."""
    return float(round(float(x), nd))


def rounded_vec(x: Sequence[float] | np.ndarray, nd: int = 4) -> list[float]:
    return [rounded(c, nd) for c in x]


def colour(rng: np.random.Generator, m: Materials, value: U) -> list[float]:
    """A reflectance: uniform hue, mostly saturated (``m.grey_prob`` grey), value ``value``."""
    h = rng.uniform()
    s = m.grey_saturation.draw(rng) if rng.random() < m.grey_prob else m.saturation.draw(rng)
    v = value.draw(rng)
    return rounded_vec(colorsys.hsv_to_rgb(h, s, v))


def tint(rng: np.random.Generator, lights: Lights) -> np.ndarray:
    """A light colour between warm and cool white, luminance 1."""
    t = rng.uniform()
    c = (1 - t) * np.array(lights.warm) + t * np.array(lights.cool)
    return c / float(c @ LUMINANCE)

"""Procedural images baked for Mitsuba: seeded value noise and a gradient sky.

Pure numpy (no Mitsuba import): :mod:`mcdenoise.render.scenes` wraps the arrays in an
in-memory ``mi.Bitmap``, so no temporary files are written.

Arrays are float32 ``(H, W, 3)`` (row 0 at the top, as ``mi.Bitmap`` reads them), linear RGB
(Rec.709 primaries), values in ``[0, inf)``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: Lattice cells across one noise tile at the coarsest octave; the tile is periodic, so a
#: texture scaled to ``scale`` cells per uv unit repeats every ``NOISE_CELLS / scale`` uv.
NOISE_CELLS = 8
#: Side of the baked noise tile in pixels (32 pixels per coarsest cell).
NOISE_SIZE = 256
#: Octaves of the fractal sum (cells 8, 16, 32 across the tile; amplitudes 1, 1/2, 1/4).
NOISE_OCTAVES = 3


def _smooth(t: np.ndarray) -> np.ndarray:
    """Quintic fade ``6t⁵ − 15t⁴ + 10t³``: C² continuous value-noise interpolation."""
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


def _value_noise(rng: np.random.Generator, cells: int, size: int) -> np.ndarray:
    """One octave of periodic value noise: ``(size, size)`` in [0, 1], ``cells`` per side."""
    lattice = rng.random((cells, cells))
    x = (np.arange(size) + 0.5) * cells / size
    i0 = np.floor(x).astype(np.int64)
    f = _smooth(x - i0)
    i0 %= cells
    i1 = (i0 + 1) % cells
    # Rows (v) then columns (u); the lattice wraps, so the tile is seamless.
    top = lattice[i0][:, i0] * (1 - f)[None, :] + lattice[i0][:, i1] * f[None, :]
    bot = lattice[i1][:, i0] * (1 - f)[None, :] + lattice[i1][:, i1] * f[None, :]
    return top * (1 - f)[:, None] + bot * f[:, None]


def value_noise(
    seed: int,
    *,
    size: int = NOISE_SIZE,
    cells: int = NOISE_CELLS,
    octaves: int = NOISE_OCTAVES,
) -> np.ndarray:
    """Seeded, tileable fractal value noise, ``(size, size)`` float32, rescaled to [0, 1].

    ``octaves`` octaves of lattice value noise with ``cells · 2^k`` cells per side and
    amplitude ``2^-k``; the same ``seed`` gives the same array on every machine (numpy's
    PCG64). The tile wraps seamlessly in both directions (for ``wrap_mode = repeat``).

    >>> n = value_noise(3, size=32, cells=4, octaves=2)
    >>> n.shape, n.dtype, float(n.min()), float(n.max())
    ((32, 32), dtype('float32'), 0.0, 1.0)
    >>> bool(np.array_equal(n, value_noise(3, size=32, cells=4, octaves=2)))
    True
    """
    if size < 2 or cells < 1 or octaves < 1:
        raise ValueError(
            f"need size >= 2, cells >= 1, octaves >= 1; got {size}, {cells}, {octaves}"
        )
    rng = np.random.default_rng(seed)
    total = np.zeros((size, size))
    for k in range(octaves):
        total += _value_noise(rng, cells * 2**k, size) * 0.5**k
    lo, hi = total.min(), total.max()
    return ((total - lo) / max(hi - lo, 1e-12)).astype(np.float32)


def noise_image(
    color0: Sequence[float], color1: Sequence[float], seed: int, *, size: int = NOISE_SIZE
) -> np.ndarray:
    """``(size, size, 3)`` float32: linear RGB blend ``color0 + n · (color1 − color0)`` of
    :func:`value_noise` ``n``."""
    n = value_noise(seed, size=size)[..., None]
    c0 = np.asarray(color0, dtype=np.float32)
    c1 = np.asarray(color1, dtype=np.float32)
    return (c0 + n * (c1 - c0)).astype(np.float32)


#: Colours (linear RGB radiance) of the procedural sky.
SKY_ZENITH = (0.18, 0.32, 0.75)
SKY_HORIZON = (0.85, 0.88, 0.95)
SKY_GROUND = (0.20, 0.17, 0.14)


def sky_image(width: int = 256, height: int = 128) -> np.ndarray:
    """A gradient sky in Mitsuba's lat-long envmap layout, ``(height, width, 3)`` float32.

    Bright horizon blending into a blue zenith (by ``sqrt`` of the up component), a dim,
    uniform ground below the horizon; no sun (add a ``sun`` light for one), so it is
    constant along each row. Up is +Y; row ``i`` samples the polar angle ``θ = π i / (H − 1)``
    from +Y, as Mitsuba's ``envmap`` reads it (first row the zenith, last the nadir).
    """
    if width < 2 or height < 2:
        raise ValueError(f"sky image needs width, height >= 2, got {width}x{height}")
    theta = np.pi * np.arange(height) / (height - 1)
    up = np.cos(theta)[:, None, None]  # y component of the direction of each row
    zenith, horizon, ground = (np.asarray(c) for c in (SKY_ZENITH, SKY_HORIZON, SKY_GROUND))
    t = np.sqrt(np.clip(up, 0.0, 1.0))
    rows = np.where(up > 0, horizon * (1 - t) + zenith * t, ground)
    return np.broadcast_to(rows, (height, width, 3)).astype(np.float32)

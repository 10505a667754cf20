"""Spatiotemporal variance-guided filtering (SVGF; Schied et al. 2017), vectorised torch.

The reference is Falcor's ``SVGFPass`` (``Source/RenderPasses/SVGFPass``: ``SVGFReproject``,
``SVGFFilterMoments``, ``SVGFAtrous``, ``SVGFCommon``, ``SVGFFinalModulate`` shaders); each
step below names the shader it follows. Per frame:

1. **Demodulate** the colour by the albedo (``SVGFReproject``: ``demodulate``), giving the
   *illumination* that is filtered, so texture never has to survive the filter.
2. **Reproject** the history of frame ``t - 1`` (``loadPrevData``): bilinear taps at
   ``p + motion`` (:mod:`mcdenoise.filters.warp`), each tap kept only when it is on the film,
   the pixel's ``motion_valid`` is 1 and it passes the consistency tests of
   ``isReprjValid``: ``|z_prev − z| / (fwidth(z) + ε_z) <= 10`` and
   ``|n − n_prev| / (fwidth(n) + 0.01) <= 16``; the weights of the kept taps are
   renormalised and at least 0.01 of them must remain. Where no bilinear tap survives but the
   motion is trusted, Falcor's fallback averages the taps of the 3×3 block around the nearest
   previous pixel that pass the same tests.

   ``motion_valid`` (which Falcor does not have) = 0 drops the history. mcdenoise's renderer
   writes 0 also in a one-pixel band along every silhouette, where it compares object ids, a
   test depth and normal cannot make (a ceiling light and its ceiling share both), so the
   band restarts its history every frame (a noisy ring around moving objects, seen by
   helper F). Keeping the band's taps that pass the depth and normal tests instead, as
   Falcor does everywhere, was tried and made the measured sequence worse: per-frame relMSE
   0.0146 -> 0.0274 over 8 frames, the light smeared over the ceiling
   (``docs/results/temporal.md``).
3. **Accumulate** (``SVGFReproject``: ``main``): history length
   ``n = min(32, n_prev + 1)`` (1 without history); exponential moving averages with
   ``α = max(0.05, 1/n)`` for the illumination and ``max(0.2, 1/n)`` for the first two
   moments of its luminance; variance ``max(0, m2 − m1²)``.
4. **Spatial variance while the history is short** (``SVGFFilterMoments``): where ``n < 4``, a
   7×7 cross-bilateral filter (luminance φ = ``phi_color``, depth φ = ``3·fwidth(z)·|o|``,
   normal power ``phi_normal``) of the illumination and the moments replaces them, with
   variance ``(m2 − m1²) · 4 / n``.
5. **À-trous wavelet filter** (``SVGFAtrous``): ``iterations`` (5, the paper's) levels of the
   5×5 B3-spline kernel ``(1, 2/3, 1/6)`` with step ``2^i``; weights
   ``exp(−|l_p − l_q| / (phi_color·sqrt(g3×3(var)_p + 1e-10)) − |z_p − z_q| /
   (fwidth(z)_p · step · |o|)) · max(0, n_p·n_q)^phi_normal`` (``computeWeight``), the centre
   with weight 1, the variance filtered with the squared weights, the luminance φ from the
   variance prefiltered by a 3×3 Gaussian (``computeVarianceCenter``).
   The output of level ``feedback_tap`` (0: the first, as in the paper; Falcor's default
   is 1 of 4) becomes the history illumination of the next frame.
6. **Remodulate** by the albedo (``SVGFFinalModulate``).

Pixels where the camera ray escaped (``depth == 0``, the buffers' convention for the
background) are accumulated over time like any other (Falcor: an environment map keeps a
valid history) but not filtered spatially (Falcor: ``zCenter.x < 0`` returns the centre).

Deviations from Falcor, all because the input is offline CPU data read from files:

* ``fwidth`` of depth and normal comes from finite differences of the buffers, not from the
  rasteriser's derivatives: per axis the smaller of the forward and backward absolute
  difference (so a pixel next to a silhouette takes its surface's own slope, not the jump;
  a background neighbour does not count), summed over x and y (``fwidth = |ddx| + |ddy|``);
  for the normal the length of that vector.
* The depth buffer is a distance in scene units of any scale, not metres: the depth test's
  floor is relative, ``ε_z = 0.01 · z`` (Falcor: an absolute ``1e-2``). The à-trous and
  moment filters' depth weights are ratios and need no change.
* No mesh ids and no emission buffer (Falcor's inputs have no ids either; the emission is
  not demodulated there). Demodulation is the project's ``color / (albedo + 0.01)``
  (:mod:`mcdenoise.filters.albedo`) instead of Falcor's ``color / max(albedo, 0.001)``.
* Normals are renormalised (pixel-averaged normals of a path tracer are shorter than 1 on
  edges; Falcor's octahedral packing normalises too); a zero normal (background) gives
  normal weight 0 against any other pixel.
* The history length is interpolated with the same taps as the history (Falcor reads it at
  the nearest pixel: "crude, fixme"). The screen-bounds test on that nearest previous pixel
  accepts the whole film (Falcor's also drops its first row and column), and a bilinear tap
  off the film is dropped (Falcor reads it as zeros, which its depth test then rejects).
* The moment filter gives the centre pixel weight 1 explicitly (Falcor's loop gives it
  ``(n·n)^128``, which is 1 for a unit normal), and the 3×3 variance blur renormalises over
  the taps on the film (Falcor reads 0 outside).
* **Warm-up filter steered by the renderer's variance.** Falcor's ``SVGFFilterMoments``
  stops at luminance differences of ``phi_color`` = 10 in absolute units, which assumes
  display-range illumination with the emission subtracted (its ``gEmission`` input). Our
  renders have neither an emission buffer nor a bounded range: a ceiling light of radiance
  ~20 next to a ceiling of ~0.4 is 2.7 φ apart, its weight exp(−2.7) = 0.07 lets it into the
  neighbours' moments, the variance estimate there explodes, and the à-trous levels then
  spread the light over the ceiling (measured: per-frame relMSE 0.68 against 0.11 for the
  noisy input on a 4-spp Cornell box). When the input has ``color_var`` (the variance of the
  mean that the temporal moments estimate, known here from the start), the warm-up filter's
  φ becomes ``phi_color · sqrt(g3×3(var))`` of that variance, as in the à-trous levels
  (``use_color_var``, on by default; without ``color_var``: Falcor's constant).
* **phi_color = 2**, not Falcor's 10. Path-traced HDR frames at 4 spp have a far wider
  range than a real-time renderer's demodulated illumination (small emitters, caustics), and
  with 10 standard deviations every edge between a bright and a dim surface of one plane
  is crossed. Chosen on frame 0 of three renders that are not the measured sequence
  (``caustics_glass``, ``dof_row``, ``textured_floors`` of the demo experiment at 128², 4 spp;
  geometric-mean relMSE over φ ∈ {10, 4, 2, 1}: 0.111, 0.088, 0.072, 0.099 with
  ``use_color_var``; 0.648 .. 0.473 without it, where the caustics' fireflies survive).
  ``-p phi_color=10`` gives Falcor's value.
* Luminances are clamped at 1e15 so that their squares, the second moments, stay finite in
  float32.
* Inputs without depth or normals drop that weight (and that reprojection test); without
  albedo the colour is filtered as it is.

Everything is shaped ``(B, C, H, W)``; on the CPU the row bands of each pass are shared by
:func:`~mcdenoise.filters.parallel.parallel_map`'s workers (results do not depend on the
thread count). Not differentiable by design (no ``torch.no_grad`` here, but the method runs
without autograd).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.filters.albedo import demodulate
from mcdenoise.filters.parallel import parallel_map
from mcdenoise.filters.svgf_guides import (
    MAX_LUMINANCE,
    Guides,
    SvgfSettings,
    luminance,
    make_guides,
)
from mcdenoise.filters.svgf_history import History, accumulate, reproject

#: 1-D B3-spline weights of the 5×5 à-trous kernel for |offset| = 0, 1, 2 (``SVGFAtrous``).
ATROUS_WEIGHTS = (1.0, 2.0 / 3.0, 1.0 / 6.0)
#: 3×3 Gaussian of the variance prefilter for |dx|, |dy| in {0, 1} (``computeVarianceCenter``).
VARIANCE_BLUR = ((1.0 / 4.0, 1.0 / 8.0), (1.0 / 8.0, 1.0 / 16.0))


# --------------------------------------------------------------------------------------------
# Spatial passes (tiles, shared by parallel_map's workers)
# --------------------------------------------------------------------------------------------
Tile = tuple[int, int, int, int]  # y0, y1, x0, x1 (output pixels, half-open)


def _bands(h: int, w: int, halo: int) -> list[Tile]:
    """Full-width row bands of about 96 rows (fastest per pixel on one thread at 1024 columns
    among 16..128), at least ``2·halo`` (so the rows read around a band do not dominate)."""
    rows = max(96, 2 * halo)
    return [(y, min(h, y + rows), 0, w) for y in range(0, h, rows)]


def _tiles(h: int, w: int, size: int = 64) -> list[Tile]:
    return [
        (y, min(h, y + size), x, min(w, x + size))
        for y in range(0, h, size)
        for x in range(0, w, size)
    ]


def _window(tile: Tile, h: int, w: int, oy: int, ox: int) -> tuple[slice, slice] | None:
    """Rows and columns of the centres ``c`` in ``tile`` whose neighbour ``c + o`` is on the
    film (``None`` if there are none)."""
    y0, y1, x0, x1 = tile
    a, b = max(y0, -oy), min(y1, h - oy)
    c, d = max(x0, -ox), min(x1, w - ox)
    if a >= b or c >= d:
        return None
    return slice(a, b), slice(c, d)


def _shift(sl: slice, by: int) -> slice:
    return slice(sl.start + by, sl.stop + by)


def _half_offsets(
    radius: int, step: int, kernel: tuple[float, ...] | None
) -> list[tuple[int, int, float, float]]:
    """One offset ``(oy, ox, log k, 1/|o|)`` of each pair ``±o`` of the ``(2r+1)²`` window
    (``o`` in units of taps, times ``step`` in pixels); ``kernel[|i|]`` are the separable
    weights (``None``: all 1)."""
    out = []
    for dy in range(0, radius + 1):
        for dx in range(-radius, radius + 1):
            if dy == 0 and dx <= 0:
                continue
            k = 1.0 if kernel is None else kernel[abs(dy)] * kernel[abs(dx)]
            out.append((dy * step, dx * step, math.log(k), 1.0 / math.hypot(dy, dx)))
    return out


def _bilateral_tile(
    tile: Tile,
    pairs: list[tuple[int, int, float, float]],
    lum: Tensor,
    neg_inv_phi_l: Tensor | float,
    neg_inv_phi_z: Tensor | None,
    g: Guides,
    phi_normal: float,
    linear: Tensor,
    squared: Tensor | None,
) -> tuple[Tensor, Tensor, Tensor | None]:
    """Sums over the window of the pixels of ``tile`` with Falcor's ``computeWeight``
    ``w = k · exp(−|Δl|/φ_l − |Δz|/(φ_z |o|)) · max(0, n·n')^phi_normal``, the centre with
    weight 1: ``(Σ w, Σ w·linear[:, 1:], Σ w²·squared)`` over the tile. Channel 0 of
    ``linear`` must be 1 (the callers prepend it), so that ``Σ w`` comes with the other sums
    in one multiply-add per tap.

    The parts of the exponent that do not depend on the centre (``|Δl|``, ``|Δz|`` and the
    normal term, which are symmetric in the two pixels) are computed once per pair ``±o``
    and read by both taps.
    """
    _, _, h, w = lum.shape
    y0, y1, x0, x1 = tile
    # channel 0 of ``linear`` is 1: Σ w and Σ w·linear in one multiply-add per tap
    sum_all = linear[..., y0:y1, x0:x1].clone()
    sum_sq = None if squared is None else squared[..., y0:y1, x0:x1].clone()
    depth, normal = g.depth, g.normal
    if neg_inv_phi_z is None:
        depth = None
    for oy, ox, log_k, inv_len in pairs:
        plus = _window(tile, h, w, oy, ox)
        minus = _window(tile, h, w, -oy, -ox)
        if plus is None and minus is None:
            continue
        # the pair's terms at p (between p and p + o), for p in both windows' needs
        need = [
            r
            for r in (
                plus,
                None if minus is None else (_shift(minus[0], -oy), _shift(minus[1], -ox)),
            )
            if r is not None
        ]
        py = slice(min(r[0].start for r in need), max(r[0].stop for r in need))
        px = slice(min(r[1].start for r in need), max(r[1].stop for r in need))
        qy, qx = _shift(py, oy), _shift(px, ox)
        dl = (lum[..., py, px] - lum[..., qy, qx]).abs_()
        dz = None if depth is None else (depth[..., py, px] - depth[..., qy, qx]).abs_()
        ln: Tensor | float = log_k
        if normal is not None:
            n0, n1 = normal[..., py, px], normal[..., qy, qx]
            dot = n0[:, 0:1] * n1[:, 0:1]
            dot.addcmul_(n0[:, 1:2], n1[:, 1:2]).addcmul_(n0[:, 2:3], n1[:, 2:3])
            ln = dot.clamp_(min=1e-30).log_().mul_(phi_normal).add_(log_k)
        for win, sign in ((plus, 1), (minus, -1)):
            if win is None:
                continue
            cy, cx = win
            # where this tap's pair terms sit in the (py, px) block
            ty = _shift(cy, -py.start - (oy if sign < 0 else 0))
            tx = _shift(cx, -px.start - (ox if sign < 0 else 0))
            ny, nx = _shift(cy, sign * oy), _shift(cx, sign * ox)
            # exponent ln + |Δl|·(−1/φ_l) + |Δz|·(−1/φ_z)/|o|, one fused op per term
            if isinstance(neg_inv_phi_l, float):
                e = dl[..., ty, tx] * neg_inv_phi_l
                e.add_(ln if isinstance(ln, float) else ln[..., ty, tx])
            elif isinstance(ln, float):
                e = dl[..., ty, tx] * neg_inv_phi_l[..., cy, cx]
                e.add_(ln)
            else:
                e = torch.addcmul(ln[..., ty, tx], dl[..., ty, tx], neg_inv_phi_l[..., cy, cx])
            if dz is not None and neg_inv_phi_z is not None:
                e.addcmul_(dz[..., ty, tx], neg_inv_phi_z[..., cy, cx], value=inv_len)
            wt = e.exp_()
            oy0, ox0 = cy.start - y0, cx.start - x0
            by, bx = slice(oy0, oy0 + (cy.stop - cy.start)), slice(ox0, ox0 + (cx.stop - cx.start))
            sum_all[..., by, bx].addcmul_(wt, linear[..., ny, nx])
            if sum_sq is not None and squared is not None:
                sum_sq[..., by, bx].addcmul_(wt.square_(), squared[..., ny, nx])
    return sum_all[:, :1], sum_all[:, 1:], sum_sq


def _variance_blur(var: Tensor) -> Tensor:
    """3×3 Gaussian of the variance (``computeVarianceCenter``), renormalised on the film."""
    _, _, h, w = var.shape
    total = torch.zeros_like(var)
    norm = torch.zeros_like(var[:1, :1])
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            win = _window((0, h, 0, w), h, w, dy, dx)
            if win is None:
                continue
            cy, cx = win
            k = VARIANCE_BLUR[abs(dy)][abs(dx)]
            total[..., cy, cx] += k * var[..., _shift(cy, dy), _shift(cx, dx)]
            norm[..., cy, cx] += k
    return total / norm


def atrous_level(
    illumination: Tensor, variance: Tensor, g: Guides, step: int, s: SvgfSettings
) -> tuple[Tensor, Tensor]:
    """One à-trous level (``SVGFAtrous``) with step ``step``: ``(illumination, variance)``."""
    _, _, h, w = illumination.shape
    lum = luminance(illumination)
    neg_inv_phi_l = -1.0 / (s.phi_color * (_variance_blur(variance) + 1e-10).sqrt())
    neg_inv_phi_z = None
    if g.depth_fwidth is not None:
        neg_inv_phi_z = -1.0 / (g.depth_fwidth.clamp_min(1e-8) * step)
    pairs = _half_offsets(2, step, ATROUS_WEIGHTS)
    ones_illum = torch.cat([torch.ones_like(lum), illumination], 1)
    out_i = torch.empty_like(illumination)
    out_v = torch.empty_like(variance)

    def run(tile: Tile) -> None:
        y0, y1, x0, x1 = tile
        sw, si, sv = _bilateral_tile(
            tile, pairs, lum, neg_inv_phi_l, neg_inv_phi_z, g, s.phi_normal, ones_illum, variance
        )
        assert sv is not None
        hit = g.hit[..., y0:y1, x0:x1]
        keep_i, keep_v = illumination[..., y0:y1, x0:x1], variance[..., y0:y1, x0:x1]
        out_i[..., y0:y1, x0:x1] = torch.where(hit, si / sw, keep_i)
        out_v[..., y0:y1, x0:x1] = torch.where(hit, sv / sw.square(), keep_v)

    parallel_map(run, _bands(h, w, 2 * step), like=illumination)
    return out_i, out_v


def _warmup_regions(short: Tensor, radius: int, bands: bool | None = None) -> list[Tile]:
    """The regions :func:`spatial_variance` computes: the 64×64 tiles holding a ``short``
    pixel, or (``bands`` None: when those tiles cover half of them or more; True: always) the
    full-width row bands holding one. Either gives the same pixels bit for bit: each pixel's
    arithmetic does not depend on the region around it."""
    _, _, h, w = short.shape
    tiles = [t for t in _tiles(h, w) if bool(short[..., t[0] : t[1], t[2] : t[3]].any())]
    if bands is False:
        return tiles
    rows = [t for t in _bands(h, w, radius) if bool(short[..., t[0] : t[1], :].any())]
    if bands or len(tiles) * 64 * 64 >= sum((y1 - y0) * w for y0, y1, _, _ in rows) // 2:
        return rows  # fewer, larger operations
    return tiles


def spatial_variance(
    illumination: Tensor,
    moments: Tensor,
    variance: Tensor,
    length: Tensor,
    g: Guides,
    s: SvgfSettings,
    frame_variance: Tensor | None = None,
) -> tuple[Tensor, Tensor]:
    """``SVGFFilterMoments``: where the history is shorter than ``spatial_history``, the
    illumination and moments filtered by a 7×7 cross-bilateral filter and the variance from
    those moments, boosted by ``4 / n``; elsewhere unchanged. Returns
    ``(illumination, variance)``. Only the 64×64 tiles holding such a pixel are computed
    (after a few frames: the disocclusions), or the full-width row bands holding one when
    those tiles cover half of the bands or more (the renderer's silhouette band restarts its
    history every frame, so short pixels are spread over the whole film: at 512² a tile's
    ~20 operations per offset on 4096 pixels cost more in per-operation overhead than the
    pixels that a band computes in vain).

    The luminance φ is Falcor's constant ``phi_color``, or, given ``frame_variance`` (the
    renderer's luminance variance of this frame's illumination, ``(B, 1, H, W)``),
    ``phi_color · sqrt(g3×3(frame_variance))`` as in the à-trous levels (see the module doc)."""
    short = (length < s.spatial_history) & g.hit
    if not bool(short.any()):
        return illumination, variance
    lum = luminance(illumination)
    neg_inv_phi_z = None
    if g.depth_fwidth is not None:
        neg_inv_phi_z = -1.0 / (g.depth_fwidth.clamp_min(1e-8) * 3.0)
    pairs = _half_offsets(s.spatial_radius, 1, None)
    neg_inv_phi_l: Tensor | float = -1.0 / s.phi_color
    if frame_variance is not None:
        blurred = _variance_blur(frame_variance.to(illumination.dtype))
        neg_inv_phi_l = -1.0 / (s.phi_color * (blurred + 1e-10).sqrt())
    out_i = illumination.clone()
    out_v = variance.clone()
    packed = torch.cat([torch.ones_like(lum), illumination, moments], 1)
    tiles = _warmup_regions(short, s.spatial_radius)

    def run(tile: Tile) -> None:
        y0, y1, x0, x1 = tile
        sw, acc, _ = _bilateral_tile(
            tile, pairs, lum, neg_inv_phi_l, neg_inv_phi_z, g, s.phi_normal, packed, None
        )
        acc = acc / sw
        m1, m2 = acc[:, 3:4], acc[:, 4:5]
        n = length[..., y0:y1, x0:x1]
        var = (m2 - m1.square()).clamp_min(0.0) * (s.spatial_history / n)
        sel = short[..., y0:y1, x0:x1]
        out_i[..., y0:y1, x0:x1] = torch.where(sel, acc[:, :3], illumination[..., y0:y1, x0:x1])
        out_v[..., y0:y1, x0:x1] = torch.where(sel, var, variance[..., y0:y1, x0:x1])

    parallel_map(run, tiles, like=illumination)
    return out_i, out_v


# --------------------------------------------------------------------------------------------
# The filter with its state
# --------------------------------------------------------------------------------------------
def _luminance_variance(color_var: Tensor, factor: Tensor | None) -> Tensor:
    """Variance of the luminance of ``color / factor`` from the colour's per-channel variance
    of the mean, the channels taken as fully correlated (Monte Carlo noise mostly is: one path
    carries all three): ``(Σ_c w_c σ_c / f_c)²``, clamped like the luminance."""
    sd = color_var.clamp_min(0.0).sqrt().expand(-1, 3, -1, -1)
    if factor is not None:
        sd = sd / factor
    return luminance(sd).clamp(0.0, MAX_LUMINANCE).square()


class Svgf:
    """SVGF over one sequence: call :meth:`step` on its frames in order.

    Example:
        >>> f = Svgf()
        >>> frame = torch.full((1, 3, 8, 8), 0.5)
        >>> out0 = f.step(frame)  # no motion: frame 0 (or a cut)
        >>> out1 = f.step(frame, motion=torch.zeros(1, 2, 8, 8))
        >>> tuple(out1.shape), bool(torch.allclose(out1, frame))
        ((1, 3, 8, 8), True)
    """

    def __init__(self, settings: SvgfSettings | None = None) -> None:
        self.settings = (settings or SvgfSettings()).checked()
        self.history: History | None = None

    def reset(self) -> None:
        """Forget the history (a cut: the next frame starts afresh)."""
        self.history = None

    def step(
        self,
        color: Tensor,
        *,
        albedo: Tensor | None = None,
        depth: Tensor | None = None,
        normal: Tensor | None = None,
        motion: Tensor | None = None,
        motion_valid: Tensor | None = None,
        color_var: Tensor | None = None,
    ) -> Tensor:
        """Denoise the next frame; returns ``(B, 3, H, W)`` linear RGB (>= 0).

        Args:
            color: ``(B, 3, H, W)`` noisy linear HDR colour (finite, sanitised).
            albedo, depth, normal: the frame's guide buffers, ``(B, 3|1|3, H, W)``, or
                ``None``.
            motion: ``(B, 2, H, W)`` motion to the previous frame (pixels, x right, y down);
                ``None`` makes this frame a cut: the history is dropped.
            motion_valid: ``(B, 1, H, W)``, 0 where the motion is not to be trusted.
            color_var: ``(B, 3 or 1, H, W)`` the renderer's variance of the mean of
                ``color``, or ``None``: steers the warm-up filter (see the module doc).

        A frame whose size differs from the history's is a cut too.
        """
        s = self.settings
        if color.ndim != 4 or color.shape[1] != 3:
            raise InputError(f"svgf: color must be (B, 3, H, W), got {tuple(color.shape)}")
        g = make_guides(depth, normal, color)
        factor = None
        if albedo is not None and s.demodulate:
            irr, factor = demodulate(color, albedo.to(color.dtype), s.albedo_eps)
        else:
            irr = color
        irr = irr.clamp(0.0, MAX_LUMINANCE)
        frame_var = None
        if color_var is not None and s.use_color_var:
            frame_var = _luminance_variance(color_var.to(irr.dtype), factor)
        hist = self.history
        if hist is not None and (motion is None or hist.illumination.shape != irr.shape):
            hist = None
        if hist is None:
            reprojected = torch.zeros_like(irr[:, :1]).expand(-1, 6, -1, -1)
            ok = torch.zeros_like(irr[:, :1], dtype=torch.bool)
        else:
            assert motion is not None
            reprojected, ok = reproject(hist, g, motion, motion_valid, s)
        illum, moments, variance, length = accumulate(irr, reprojected, ok, s)
        feedback = illum
        illum_f, var_f = spatial_variance(illum, moments, variance, length, g, s, frame_var)
        for i in range(s.iterations):
            illum_f, var_f = atrous_level(illum_f, var_f, g, 1 << i, s)
            if i == min(s.feedback_tap, s.iterations - 1):
                feedback = illum_f
        self.history = History(feedback, moments, length, g)
        out = illum_f if factor is None else illum_f * factor
        return torch.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0).clamp_min(0.0)


__all__ = [
    "ATROUS_WEIGHTS",
    "Svgf",
    "atrous_level",
    "spatial_variance",
]

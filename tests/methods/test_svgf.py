"""Tests of svgf: the filter (mcdenoise.filters.svgf) against a per-pixel transcription of
Falcor's shaders, its history over frames, cuts, and the registered temporal method."""

from __future__ import annotations

import itertools
import math

import pytest
import torch
from noisy_scene import make_scene, relmse

from mcdenoise.errors import InputError
from mcdenoise.filters import svgf as S
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.registry import get_method

CPU = torch.device("cpu")


def _frames(n: int, h: int = 48, w: int = 48, noise: float = 0.15, cut_at: int | None = None):
    """A static scene with independent noise per frame (zero motion, motion_valid 1 except in
    frame 0 and at ``cut_at``): ``[(FeatureBuffers, clean (3, H, W))]``."""
    out = []
    for t in range(n):
        s = make_scene(h, w, seed=100 + t, noise=noise)
        valid = 0.0 if t == 0 or t == cut_at else 1.0
        fb = FeatureBuffers(
            {
                "color": s.noisy[0],
                "albedo": s.albedo[0],
                "normal": s.normal[0],
                "depth": s.depth[0],
                "motion": torch.zeros(2, h, w),
                "motion_valid": torch.full((1, h, w), valid),
            }
        )
        out.append((fb, s.clean[0].float()))
    return out


def _run(frames, **params):
    m = get_method("svgf")
    return list(m.run_frames([f for f, _ in frames], m.resolve_params(params), CPU))


# --- the temporal behaviour ------------------------------------------------------------------
def test_error_falls_as_frames_accumulate() -> None:
    frames = _frames(8)
    errs = [relmse(o, c) for (_, c), o in zip(frames, _run(frames))]
    noisy = [relmse(f.color, c) for f, c in frames]
    assert all(e < 0.2 * n for e, n in zip(errs, noisy))
    assert errs[-1] < 0.75 * errs[0], errs
    assert max(errs[4:]) < errs[0], errs


def test_the_accumulated_illumination_converges_like_a_running_mean() -> None:
    """Without the spatial filter (iterations 0) and after the spatial estimate (history
    >= 4), the output is the EMA of the frames with α = max(0.05, 1/n): its error falls as
    about 1/n."""
    frames = _frames(12, noise=0.3)
    errs = [relmse(o, c) for (_, c), o in zip(frames, _run(frames, iterations=0))]
    later = errs[3:]
    assert all(b < a for a, b in itertools.pairwise(later)), errs
    assert errs[-1] < 0.45 * errs[3], errs


def test_a_cut_drops_the_history() -> None:
    """motion_valid all 0 at frame 5: its output is what a fresh filter gives on it."""
    frames = _frames(7, cut_at=5)
    outs = _run(frames)
    fresh = _run(frames[5:6])
    assert torch.equal(outs[5], fresh[0])
    # frame 6 continues from the cut, as frame 1 continues from frame 0
    restarted = _run(frames[5:7])
    assert torch.equal(outs[6], restarted[1])
    # without the cut the history changes frame 5's output
    assert not torch.equal(_run(_frames(6))[5], fresh[0])


def test_a_frame_without_motion_is_a_cut() -> None:
    frames = _frames(4)
    frames[3][0].buffers.pop("motion")
    outs = _run(frames)
    assert torch.equal(outs[3], _run(frames[3:4])[0])


def test_one_frame_sequence_and_a_still_work() -> None:
    s = make_scene(40, 36, seed=1)
    still = FeatureBuffers({"color": s.noisy[0], "albedo": s.albedo[0], "normal": s.normal[0]})
    (out,) = _run([(still, None)])
    assert out.shape == (3, 40, 36) and bool(torch.isfinite(out).all())
    assert relmse(out, s.clean[0].float()) < 0.5 * relmse(still.color, s.clean[0].float())
    colour_only = FeatureBuffers({"color": s.noisy[0]})
    (out2,) = _run([(colour_only, None)])
    assert bool(torch.isfinite(out2).all())
    from mcdenoise.denoise import denoise

    res = denoise(still, "svgf")
    assert torch.allclose(res.image, out.clamp_min(0.0))


def test_frames_of_different_sizes_are_refused() -> None:
    a = FeatureBuffers({"color": torch.rand(3, 16, 16)})
    b = FeatureBuffers({"color": torch.rand(3, 16, 20)})
    with pytest.raises(InputError, match="frame 1 is 20x16 but the sequence is 16x16"):
        _run([(a, None), (b, None)])


@pytest.mark.parametrize(
    "color",
    [
        torch.zeros(3, 32, 32),
        torch.full((3, 32, 32), 3e38),
        torch.rand(3, 32, 32, generator=torch.Generator().manual_seed(0)) * 1e30,
    ],
    ids=["zeros", "float_max", "huge_random"],
)
def test_output_is_finite_on_hard_inputs(color: torch.Tensor) -> None:
    depth = torch.ones(1, 32, 32)
    depth[..., :8, :] = 0.0  # background rows
    normal = torch.zeros(3, 32, 32)
    normal[2] = 1.0
    frames = []
    for t in range(5):
        fb = FeatureBuffers(
            {
                "color": color,
                "albedo": torch.zeros(3, 32, 32),
                "depth": depth,
                "normal": normal,
                "motion": torch.full((2, 32, 32), 0.5 * t),
                "motion_valid": torch.ones(1, 32, 32),
            }
        )
        frames.append((fb, None))
    for out in _run(frames):
        assert bool(torch.isfinite(out).all()) and bool((out >= 0).all())


def test_reprojection_follows_the_motion_without_ghosting() -> None:
    """A noise-free pattern moving 2 px right per frame: the reprojected history is the
    current frame wherever it is valid, so the accumulated image equals the input there."""
    h, w = 24, 32
    g = torch.Generator().manual_seed(3)
    base = torch.rand(3, h, w + 20, generator=g) + 0.1
    f = S.Svgf(S.SvgfSettings(iterations=0, spatial_history=0.0))
    for t in range(5):
        frame = base[:, :, 20 - 2 * t : 20 - 2 * t + w][None]  # content moves right
        motion = torch.zeros(1, 2, h, w)
        motion[:, 0] = -2.0  # the surface at p was 2 px to the left
        out = f.step(frame, motion=motion if t else None)
        valid = slice(2, None)  # the first two columns have no history
        torch.testing.assert_close(out[..., valid], frame[..., valid], atol=1e-5, rtol=1e-5)
    # column x was first seen x // 2 frames ago (entering at the left edge)
    want = (torch.arange(w) // 2 + 1).clamp(max=5).float().expand(1, 1, h, w)
    assert torch.equal(f.history.length, want)  # type: ignore[union-attr]


def test_the_depth_test_rejects_another_surface() -> None:
    """Zero motion and motion_valid 1, but the depth jumped by 50 %: no history."""
    g = torch.Generator().manual_seed(4)
    c0, c1 = torch.rand(1, 3, 16, 16, generator=g), torch.rand(1, 3, 16, 16, generator=g)
    zero = torch.zeros(1, 2, 16, 16)
    f = S.Svgf()
    f.step(c0, depth=torch.ones(1, 1, 16, 16))
    out = f.step(c1, depth=torch.full((1, 1, 16, 16), 1.5), motion=zero)
    fresh = S.Svgf().step(c1, depth=torch.full((1, 1, 16, 16), 1.5))
    assert torch.equal(out, fresh)
    same = f.step(c1, depth=torch.full((1, 1, 16, 16), 1.5), motion=zero)
    assert not torch.equal(same, fresh)  # the same depth again: the history is used


# --- the filter against Falcor's shaders, pixel by pixel --------------------------------------
def _lum(c: torch.Tensor) -> float:
    return float(0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2])


def _weight(zc, zp, phi_z, nc, np_, phi_n, lc, lp, phi_l) -> float:
    """``computeWeight`` of SVGFCommon.slang."""
    wn = max(0.0, float(nc @ np_)) ** phi_n
    wz = 0.0 if phi_z == 0 else abs(zc - zp) / phi_z
    wl = abs(lc - lp) / phi_l
    return math.exp(-max(wl, 0.0) - max(wz, 0.0)) * wn


def _guide_scene(h: int = 10, w: int = 12):
    g = torch.Generator().manual_seed(7)
    illum = torch.rand(1, 3, h, w, generator=g, dtype=torch.float64)
    var = torch.rand(1, 1, h, w, generator=g, dtype=torch.float64) * 0.05
    depth = 1.0 + torch.rand(1, 1, h, w, generator=g, dtype=torch.float64) * 0.05
    depth[..., 0:2, 0:3] = 0.0  # background
    depth[..., 5:, 6:] += 0.5  # a step
    normal = torch.randn(1, 3, h, w, generator=g, dtype=torch.float64) * 0.1
    normal[:, 2] += 1.0
    normal[..., 0:2, 0:3] = 0.0
    return illum, var, S.make_guides(depth, normal, illum)


def test_atrous_level_matches_falcors_shader() -> None:
    illum, var, gd = _guide_scene()
    s = S.SvgfSettings()
    step = 2
    got_i, got_v = S.atrous_level(illum, var, gd, step, s)
    _, _, h, w = illum.shape
    kw = S.ATROUS_WEIGHTS
    blur = S.VARIANCE_BLUR
    for y in range(h):
        for x in range(w):
            zc = float(gd.depth[0, 0, y, x])
            if zc <= 0:
                assert torch.equal(got_i[0, :, y, x], illum[0, :, y, x])
                continue
            # computeVarianceCenter (renormalised on the film)
            vs = ks = 0.0
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    if 0 <= y + dy < h and 0 <= x + dx < w:
                        k = blur[abs(dy)][abs(dx)]
                        vs += k * float(var[0, 0, y + dy, x + dx])
                        ks += k
            phi_l = s.phi_color * math.sqrt(max(0.0, 1e-10 + vs / ks))
            phi_z = max(float(gd.depth_fwidth[0, 0, y, x]), 1e-8) * step
            nc = gd.normal[0, :, y, x]
            lc = _lum(illum[0, :, y, x])
            sw, si, sv = 1.0, illum[0, :, y, x].clone(), float(var[0, 0, y, x])
            for yy in range(-2, 3):
                for xx in range(-2, 3):
                    py, px = y + yy * step, x + xx * step
                    if not (0 <= py < h and 0 <= px < w) or (yy == 0 and xx == 0):
                        continue
                    wgt = _weight(
                        zc,
                        float(gd.depth[0, 0, py, px]),
                        phi_z * math.hypot(xx, yy),
                        nc,
                        gd.normal[0, :, py, px],
                        s.phi_normal,
                        lc,
                        _lum(illum[0, :, py, px]),
                        phi_l,
                    ) * (kw[abs(xx)] * kw[abs(yy)])
                    sw += wgt
                    si = si + wgt * illum[0, :, py, px]
                    sv += wgt * wgt * float(var[0, 0, py, px])
            torch.testing.assert_close(got_i[0, :, y, x], si / sw, atol=1e-10, rtol=1e-9)
            assert float(got_v[0, 0, y, x]) == pytest.approx(sv / sw**2, rel=1e-9, abs=1e-14)


def test_spatial_variance_matches_falcors_filter_moments() -> None:
    illum, _, gd = _guide_scene()
    lum = 0.2126 * illum[:, 0:1] + 0.7152 * illum[:, 1:2] + 0.0722 * illum[:, 2:3]
    moments = torch.cat([lum, lum.square() * 1.1], 1)
    length = torch.ones_like(lum)
    length[..., :, 8:] = 6.0  # enough history there: unchanged
    var_in = torch.full_like(lum, 0.123)
    s = S.SvgfSettings()
    got_i, got_v = S.spatial_variance(illum, moments, var_in, length, gd, s)
    _, _, h, w = illum.shape
    for y in range(h):
        for x in range(w):
            zc = float(gd.depth[0, 0, y, x])
            if zc <= 0 or float(length[0, 0, y, x]) >= 4:
                assert torch.equal(got_i[0, :, y, x], illum[0, :, y, x])
                assert float(got_v[0, 0, y, x]) == 0.123
                continue
            phi_z = max(float(gd.depth_fwidth[0, 0, y, x]), 1e-8) * 3.0
            nc = gd.normal[0, :, y, x]
            lc = _lum(illum[0, :, y, x])
            sw, si, sm = 0.0, torch.zeros(3, dtype=illum.dtype), torch.zeros(2, dtype=illum.dtype)
            for yy in range(-3, 4):
                for xx in range(-3, 4):
                    py, px = y + yy, x + xx
                    if not (0 <= py < h and 0 <= px < w):
                        continue
                    if yy == 0 and xx == 0:
                        wgt = 1.0  # (n·n)^128 = 1 for the unit normal
                    else:
                        wgt = _weight(
                            zc,
                            float(gd.depth[0, 0, py, px]),
                            phi_z * math.hypot(xx, yy),
                            nc,
                            gd.normal[0, :, py, px],
                            s.phi_normal,
                            lc,
                            _lum(illum[0, :, py, px]),
                            s.phi_color,
                        )
                    sw += wgt
                    si = si + wgt * illum[0, :, py, px]
                    sm = sm + wgt * moments[0, :, py, px]
            sm = sm / sw
            want_v = max(0.0, float(sm[1] - sm[0] ** 2)) * 4.0 / float(length[0, 0, y, x])
            torch.testing.assert_close(got_i[0, :, y, x], si / sw, atol=1e-10, rtol=1e-9)
            assert float(got_v[0, 0, y, x]) == pytest.approx(want_v, rel=1e-8, abs=1e-14)


def test_accumulate_is_falcors_ema() -> None:
    s = S.SvgfSettings()
    illum = torch.full((1, 3, 1, 3), 2.0, dtype=torch.float64)
    prev = torch.zeros(1, 6, 1, 3, dtype=torch.float64)
    prev[:, :3] = 1.0
    prev[:, 3] = 1.0
    prev[:, 4] = 1.5
    prev[:, 5] = torch.tensor([1.0, 9.0, 40.0], dtype=torch.float64)
    ok = torch.tensor([True, True, False]).view(1, 1, 1, 3)
    out, m, var, n = S.accumulate(illum, prev, ok, s)
    assert n.flatten().tolist() == [2.0, 10.0, 1.0]
    a = torch.tensor([0.5, 0.1, 1.0], dtype=torch.float64)  # max(0.05, 1/n); 1 without history
    am = torch.tensor([0.5, 0.2, 1.0], dtype=torch.float64)  # max(0.2, 1/n)
    torch.testing.assert_close(out[0, 0, 0], 1.0 + a * (2.0 - 1.0))
    torch.testing.assert_close(m[0, 0, 0], 1.0 + am * (2.0 - 1.0))
    torch.testing.assert_close(m[0, 1, 0], 1.5 + am * (4.0 - 1.5))
    torch.testing.assert_close(var[0, 0, 0], (m[0, 1, 0] - m[0, 0, 0] ** 2).clamp_min(0))


def test_warm_up_filter_over_bands_equals_the_tiles_bit_for_bit(monkeypatch) -> None:
    """spatial_variance computes either the 64x64 tiles holding a short-history pixel or the
    row bands holding one; both must give identical pixels (float32, the method's dtype)."""
    h, w = 150, 140  # partial tiles and bands at the borders
    g = torch.Generator().manual_seed(3)
    illum = torch.rand(1, 3, h, w, generator=g) * 4.0
    lum = S.luminance(illum)
    moments = torch.cat([lum, lum.square() * 1.1], 1)
    var = torch.rand(1, 1, h, w, generator=g) * 0.1
    depth = 1.0 + torch.rand(1, 1, h, w, generator=g) * 0.05
    depth[..., :20, :30] = 0.0
    normal = torch.randn(1, 3, h, w, generator=g) * 0.2
    normal[:, 2] += 1.0
    gd = S.make_guides(depth, normal, illum)
    length = torch.full((1, 1, h, w), 8.0)
    length[..., ::9, ::7] = 2.0  # sparse but in every tile: the bands are chosen
    short = (length < 4.0) & gd.hit
    assert S._warmup_regions(short, 3) == S._warmup_regions(short, 3, bands=True)
    s = S.SvgfSettings()
    fv = torch.rand(1, 1, h, w, generator=g) * 0.05
    banded = S.spatial_variance(illum, moments, var, length, gd, s, fv)
    original = S._warmup_regions
    monkeypatch.setattr(S, "_warmup_regions", lambda m, r: original(m, r, bands=False))
    tiled = S.spatial_variance(illum, moments, var, length, gd, s, fv)
    for a, b in zip(banded, tiled):
        assert torch.equal(a, b)
    assert not torch.equal(banded[0], illum)  # the filter did run


def test_results_do_not_depend_on_the_thread_count() -> None:
    frames = _frames(3, h=40, w=200)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = _run(frames)
        torch.set_num_threads(2)
        two = _run(frames)
    finally:
        torch.set_num_threads(before)
    for a, b in zip(one, two):
        assert torch.equal(a, b)


def test_bad_settings_are_one_line_errors() -> None:
    with pytest.raises(InputError, match="alpha"):
        _run(_frames(1), alpha=0.0)
    with pytest.raises(InputError, match="iterations"):
        _run(_frames(1), iterations=-1)


def test_it_is_registered_as_a_low_priority_temporal_method() -> None:
    m = get_method("svgf")
    assert m.temporal and m.run_sequence is not None
    assert m.requires == ("color",)
    assert m.priority < get_method("nlm").priority
    assert m.accepts(FeatureBuffers({"color": torch.zeros(3, 4, 4)})) is None


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu() -> None:
    frames = _frames(5)
    m = get_method("svgf")
    params = m.resolve_params(None)
    cpu = list(m.run_frames([f for f, _ in frames], params, CPU))
    gpu = list(m.run_frames([f.to("cuda") for f, _ in frames], params, torch.device("cuda")))
    for a, b in zip(cpu, gpu):
        torch.testing.assert_close(b.cpu(), a, atol=1e-4, rtol=1e-4)


def test_a_bright_light_does_not_spread_over_its_plane() -> None:
    """A light of radiance 25 in a ceiling of 0.3 (one plane: same depth and normal), its edge
    pixels partly covered, 4-spp-like noise with its variance: the ceiling two pixels away
    stays near 0.3. Falcor's φ = 10 with
    its absolute warm-up φ spreads the light (the reason for the defaults, module doc)."""
    g = torch.Generator().manual_seed(8)
    h = w = 40
    clean = torch.full((3, h, w), 0.3)
    clean[:, 15:25, 15:25] = 6.5  # its edge pixels are partly covered by the light ...
    clean[:, 16:24, 16:24] = 25.0
    var = (0.05 * clean) ** 2
    var[:, 15:25, 15:25] = 29.0  # ... and noisy: 4 samples either hit it or not
    var[:, 16:24, 16:24] = (0.05 * 25.0) ** 2
    noisy = (clean + var.sqrt() * torch.randn(3, h, w, generator=g)).clamp_min(0)
    fb = FeatureBuffers(
        {
            "color": noisy,
            "color_var": var,
            "albedo": torch.full((3, h, w), 0.7),
            "normal": torch.tensor([0.0, -1.0, 0.0]).view(3, 1, 1).expand(3, h, w),
            "depth": torch.full((1, h, w), 3.0),
        }
    )
    ring = torch.zeros(h, w, dtype=torch.bool)
    ring[12:28, 12:28] = True
    ring[14:26, 14:26] = False  # pixels 2..4 away from the light
    (out,) = _run([(fb, None)])
    assert float(out[:, ring].max()) < 0.45
    (falcor,) = _run([(fb, None)], phi_color=10.0, use_color_var=False)
    assert float(falcor[:, ring].max()) > 0.6


def test_guides_with_variances_are_prefiltered() -> None:
    s = make_scene(32, 32, seed=2)
    g = torch.Generator().manual_seed(9)
    noisy_albedo = (
        s.albedo[0] + 0.1 * torch.randn(3, 32, 32, generator=g, dtype=s.albedo.dtype)
    ).clamp(0, 1)
    fb = FeatureBuffers(
        {
            "color": s.noisy[0],
            "albedo": noisy_albedo,
            "albedo_var": torch.full((3, 32, 32), 0.01),
        }
    )
    (fast,) = _run([(fb, None)])
    (off,) = _run([(fb, None)], prefilter="off")
    clean = s.clean[0].float()
    assert relmse(fast, clean) < 0.8 * relmse(off, clean)
    with pytest.raises(InputError, match="prefilter must be one of off, fast, full"):
        _run([(fb, None)], prefilter="maybe")

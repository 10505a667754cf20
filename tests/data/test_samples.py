"""Tests of ``data/make_samples.py`` and of the sample renders it ships in ``data/samples/``.

The heart is :func:`test_variance_of_the_mean_matches_repeated_renders`: the per-pixel
variance of the mean that the script derives from Mitsuba's ``moment`` integrator must match
the variance of the pixel means observed over independent renders.
"""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "data" / "make_samples.py"
SAMPLES = ROOT / "data" / "samples"
SCENES = ("cornell", "materials", "caustic", "dof")
NOISY_SPP = (4, 16)
FEATURES = ("color", "albedo", "normal", "depth", "position")
NOISY_BUFFERS = {*FEATURES, *(f + "_var" for f in FEATURES)}


@pytest.fixture(scope="module")
def ms() -> ModuleType:
    """``data/make_samples.py`` imported as a module (it imports Mitsuba lazily)."""
    name = "mcdenoise_data_make_samples"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses need the module registered
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def mitsuba_variant(ms: ModuleType) -> str:
    pytest.importorskip("mitsuba")
    return ms.select_variant(None)


# --- the script's own helpers (the estimator is the library's: tests/render/test_generate.py)
@pytest.mark.parametrize(("spp", "pass_spp"), [(1024, 128), (1000, 128), (5, 128), (16384, 100)])
def test_reference_passes_cover_spp_with_distinct_seeds(
    ms: ModuleType, spp: int, pass_spp: int
) -> None:
    passes = ms.reference_seeds(7, spp, pass_spp)
    assert sum(n for _, n in passes) == spp
    assert all(1 <= n <= pass_spp for _, n in passes)
    seeds = [s for s, _ in passes]
    assert len(set(seeds)) == len(seeds) and seeds[0] == 7


def test_relmse_definition(ms: ModuleType) -> None:
    r = np.array([[[0.0, 1.0]]], dtype=np.float32)
    x = np.array([[[0.1, 1.5]]], dtype=np.float32)
    want = (0.01 / 0.01 + 0.25 / 1.01) / 2
    assert ms.relmse(x, r) == pytest.approx(want, rel=1e-6)
    assert ms.relmse(r, r) == 0.0


# --- rendering with Mitsuba ------------------------------------------------------------------
@pytest.mark.mitsuba
def test_render_buffers_layout_and_consistency(ms: ModuleType, mitsuba_variant: str) -> None:
    """Buffers have the right shapes; features agree with the geometry of a pinhole camera."""
    size = 24
    scene = ms.load_scene("cornell", size)
    b = ms.render_buffers(scene, 4, 3)
    assert set(b) == NOISY_BUFFERS
    for name, arr in b.items():
        base = name.removesuffix("_var")
        channels = 1 if base == "depth" else 3
        assert arr.shape == (channels, size, size), name
        assert arr.dtype == np.float32 and np.isfinite(arr).all(), name
        if name.endswith("_var"):
            assert arr.min() >= 0.0, name
    assert 0.0 < float(b["color"].mean()) < 10.0
    # Pixels whose 4 samples all hit the same wall: zero normal variance. There the normal is
    # a unit vector and |position - camera origin| equals the depth (distance along the ray).
    flat = (b["normal_var"].max(axis=0) == 0) & (b["depth"][0] > 0)
    assert flat.mean() > 0.5
    np.testing.assert_allclose(np.linalg.norm(b["normal"], axis=0)[flat], 1.0, atol=1e-4)
    origin = np.array([0.0, 0.0, 3.9])  # mi.cornell_box() camera
    dist = np.linalg.norm(b["position"] - origin[:, None, None], axis=0)
    rel = np.abs(dist[flat] - b["depth"][0][flat]) / b["depth"][0][flat]
    assert float(np.median(rel)) < 1e-3
    # Diffuse walls and boxes: albedo in [0, 1].
    assert 0.0 <= b["albedo"].min() and b["albedo"].max() <= 1.0


@pytest.mark.mitsuba
def test_variance_of_the_mean_matches_repeated_renders(
    ms: ModuleType, mitsuba_variant: str
) -> None:
    """K independent renders at the same spp: the empirical variance of the per-pixel means
    must match the mean predicted variance of the mean (ratio of image means within 15 %,
    25 % for depth/position whose few silhouette pixels against the background (depth 0)
    dominate; per-pixel correlation > 0.8). Dividing by spp instead of spp - 1 gives ~0.75
    at 4 spp and fails; a wrong channel mapping fails too. The thin-lens scene gives every
    feature real within-pixel variance (defocus, textures, edges)."""
    size, spp, k = 48, 4, 16
    scene = ms.load_scene("dof", size)
    runs = [ms.render_buffers(scene, spp, 500 + i) for i in range(k)]
    tolerance = {"color": 0.15, "albedo": 0.15, "normal": 0.15, "depth": 0.25, "position": 0.25}
    for name, tol in tolerance.items():
        means = np.stack([r[name] for r in runs]).astype(np.float64)
        empirical = means.var(axis=0, ddof=1)
        predicted = np.stack([r[name + "_var"] for r in runs]).astype(np.float64).mean(axis=0)
        assert (empirical > 0).mean() > 0.2, f"{name}: too few pixels with variance"
        ratio = predicted.mean() / empirical.mean()
        assert abs(ratio - 1.0) < tol, f"{name}: predicted/empirical variance = {ratio:.3f}"
        corr = np.corrcoef(empirical.ravel(), predicted.ravel())[0, 1]
        assert corr > 0.8, f"{name}: per-pixel correlation {corr:.3f}"


@pytest.mark.mitsuba
def test_missing_film_channel_is_named(ms: ModuleType, mitsuba_variant: str) -> None:
    import mitsuba as mi

    scene_dict = ms.build_scene("cornell", 8)
    scene_dict["integrator"]["inner"]["aovs"] = "albedo:albedo,normal:sh_normal"
    from mcdenoise.errors import InputError

    with pytest.raises(InputError, match=r"inner\.depth\.T.*it has .*inner\.albedo\.R"):
        ms.render_buffers(mi.load_dict(scene_dict), 1, 0)


def test_unknown_scene_is_rejected(ms: ModuleType) -> None:
    with pytest.raises(ValueError, match="unknown scene 'nope'"):
        ms.build_scene("nope", 8)


# --- the shipped files -----------------------------------------------------------------------
@pytest.fixture(scope="module")
def readme() -> str:
    return (SAMPLES / "README.md").read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def readme_size(readme: str) -> tuple[int, int]:
    m = re.search(r"resolution: (\d+)x(\d+) pixels \(width x height\)", readme)
    assert m, "data/samples/README.md does not record the resolution"
    return int(m.group(1)), int(m.group(2))


def _load(path: Path):  # -> FeatureBuffers
    from mcdenoise.io import load_buffers

    return load_buffers(path)


def test_samples_folder_is_small_and_complete(readme: str) -> None:
    files = sorted(p for p in SAMPLES.rglob("*") if p.is_file())
    total = sum(p.stat().st_size for p in files)
    assert total <= 5 * 1024 * 1024, f"data/samples is {total / 2**20:.1f} MiB"
    expected = {f"{s}_spp{n}.exr" for s in SCENES for n in NOISY_SPP}
    expected |= {f"ref/{s}.exr" for s in SCENES} | {"README.md"}
    assert {p.relative_to(SAMPLES).as_posix() for p in files} == expected
    assert "python data/make_samples.py --out data/samples" in readme
    for scene in SCENES:
        assert f"`{scene}`" in readme


@pytest.mark.parametrize("scene", SCENES)
def test_shipped_scene_files(scene: str, readme_size: tuple[int, int]) -> None:
    width, height = readme_size
    ref = _load(SAMPLES / "ref" / f"{scene}.exr")
    assert ref.shape == (height, width)
    assert ref.spp is not None and ref.spp >= 1024
    assert "color" in ref.names()
    r = ref["color"].numpy()
    assert np.isfinite(r).all() and r.min() >= 0.0
    # Lit, not black, not blown out (linear HDR colour, mean over the image).
    assert 0.05 < float(r.mean()) < 2.0
    errors = {}
    for spp in NOISY_SPP:
        fb = _load(SAMPLES / f"{scene}_spp{spp}.exr")
        assert set(fb.names()) == NOISY_BUFFERS
        assert fb.shape == (height, width)
        assert fb.spp == spp
        attrs = fb.attributes
        assert attrs["mcdenoise:scene"] == scene
        for key in ("mcdenoise:seed", "mcdenoise:variant", "mcdenoise:render_seconds"):
            assert key in attrs, key
        assert str(attrs["mitsuba:version"]).startswith("3.")
        for name in fb.names():
            t = fb[name]
            assert bool(t.isfinite().all()), f"{scene} {spp} spp: {name} has NaN/Inf"
            if name.endswith("_var"):
                assert float(t.min()) >= 0.0, name
        x = fb["color"].numpy()
        errors[spp] = float(np.mean((x - r) ** 2 / (r * r + 0.01)))
        # The predicted noise explains the observed error: E[(x - r)^2] = var(x) + var(r),
        # and var(r) is negligible (>= 1024 spp against <= 16).
        predicted = float(fb["color_var"].mean())
        observed = float(np.mean((x - r) ** 2))
        assert 0.5 < observed / predicted < 2.0, f"{scene} {spp} spp: {observed / predicted:.3f}"
    assert errors[16] < errors[4], (
        f"{scene}: relMSE 16 spp {errors[16]:.4g} >= 4 spp {errors[4]:.4g}"
    )

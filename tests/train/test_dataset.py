"""Data set scanning, the image split, loading reports and the patch sampler."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import torch

from mcdenoise.errors import InputError
from mcdenoise.io import load_buffers, save_buffers
from mcdenoise.train.patches import (
    PatchSampler,
    check_reference,
    error_map,
    image_relmse,
    load_items,
    scan_dataset,
    split_images,
)


def _prepare(buffers, ref):
    return {"color": buffers["color"], "reference": ref}


def test_scan_finds_every_level_and_filters_levels(tiny_dataset: Path) -> None:
    entries = scan_dataset(tiny_dataset)
    assert len(entries) == 8 and {e.spp for e in entries} == {4, 16}
    assert all(e.reference == tiny_dataset / "ref" / e.path.name for e in entries)
    assert {e.part for e in scan_dataset(tiny_dataset, levels=[16])} == {"spp16"}
    with pytest.raises(InputError, match="no input EXR"):
        scan_dataset(tiny_dataset, levels=[64])
    with pytest.raises(InputError, match="not a folder"):
        scan_dataset(tiny_dataset / "nope")


def test_split_is_by_image_seeded_and_disjoint(tiny_dataset: Path) -> None:
    entries = scan_dataset(tiny_dataset)
    tr, va = split_images(entries, 0.25, seed=3)
    assert {e.image for e in tr}.isdisjoint({e.image for e in va})
    assert len({e.image for e in va}) == 1 and len(tr) + len(va) == len(entries)
    assert split_images(entries, 0.25, seed=3) == (tr, va)
    others = {tuple(e.image for e in split_images(entries, 0.25, seed=s)[1]) for s in range(8)}
    assert len(others) > 1
    tr2, va2 = split_images(entries, 0.25, seed=3, max_images=2)
    assert len({e.image for e in tr2 + va2}) == 2


def test_bad_images_are_reported_with_file_and_reason(tiny_dataset: Path, tmp_path: Path) -> None:
    data = tmp_path / "set"
    shutil.copytree(tiny_dataset, data)
    ref = load_buffers(data / "ref" / "cornell.exr")
    ref["color"] = torch.where(torch.rand_like(ref["color"]) < 0.01, torch.nan, ref["color"])
    save_buffers(data / "ref" / "cornell.exr", ref)
    ref = load_buffers(data / "ref" / "dof.exr")
    ref["color"] = torch.full_like(ref["color"], 0.5)
    save_buffers(data / "ref" / "dof.exr", ref)
    items, report = load_items(scan_dataset(data), _prepare)
    assert len(items) == 4 and report.used == 4
    reasons = dict(report.skipped)
    assert "NaN/Inf" in reasons["cornell.exr[spp4]"] and "constant" in reasons["dof.exr[spp16]"]
    assert "skipped cornell.exr[spp4]" in report.summary()
    assert check_reference(torch.ones(3, 4, 4)) == "reference is constant"


def test_sampler_crops_masks_and_importance(tiny_dataset: Path) -> None:
    items, _ = load_items(scan_dataset(tiny_dataset), _prepare)
    s = PatchSampler(items, patch=16, margin=4, importance=0.5)
    b = s.batch(6, torch.Generator().manual_seed(0))
    assert b["color"].shape == (6, 3, 24, 24) and b["mask"].shape == (6, 1, 24, 24)
    again = s.batch(6, torch.Generator().manual_seed(0))
    assert all(torch.equal(b[k], again[k]) for k in b)
    # interior crop: only the centre counts; a crop on the image corner keeps its border strips
    inner = s.mask(8, 8, (40, 40))[0]
    assert inner.sum() == 16 * 16 and inner[4:20, 4:20].all()
    corner = s.mask(0, 0, (40, 40))[0]
    assert corner[:20, :20].all() and corner.sum() == 20 * 20
    far = s.mask(16, 16, (40, 40))[0]
    assert far[4:, 4:].all() and far.sum() == 20 * 20
    # importance: an image whose noisy input is far worse is drawn far more often
    for i, it in enumerate(items):
        it.tensors["tag"] = torch.full((1, *it.size), float(i))
    items[0].tensors["color"] = items[0].tensors["color"] * 10
    s = PatchSampler(items, patch=16, margin=4, importance=1.0)
    tags = s.batch(200, torch.Generator().manual_seed(1))["tag"][:, 0, 0, 0]
    assert float((tags == 0).float().mean()) > 0.5  # uniform would give 1/8
    s = PatchSampler(items, patch=16, margin=4, importance=0.0)
    tags = s.batch(400, torch.Generator().manual_seed(1))["tag"][:, 0, 0, 0]
    assert 0.05 < float((tags == 0).float().mean()) < 0.25
    with pytest.raises(InputError, match="smaller than"):
        PatchSampler(items, patch=40, margin=4)


def test_error_map_is_the_per_pixel_relmse_with_nonfinite_noise_as_zero() -> None:
    ref = torch.full((3, 2, 2), 0.5)
    noisy = ref.clone()
    noisy[:, 0, 0] = 1.5  # (1.5 - 0.5)² / (0.25 + 0.01) in each channel
    noisy[0, 1, 1] = float("nan")  # read as 0: (0 - 0.5)² / 0.26 in one channel of three
    m = error_map(noisy, ref)
    assert m.shape == (2, 2)
    assert float(m[0, 0]) == pytest.approx(1 / 0.26, rel=1e-6)
    assert float(m[1, 1]) == pytest.approx(0.25 / 0.26 / 3, rel=1e-6)
    assert float(m[0, 1]) == 0.0 and float(m[1, 0]) == 0.0


def test_image_relmse_is_the_float64_relmse_of_the_metrics() -> None:
    from mcdenoise.eval.metrics import relmse as metric_relmse

    g = torch.Generator().manual_seed(0)
    out, ref = torch.rand(3, 5, 7, generator=g) * 4, torch.rand(3, 5, 7, generator=g)
    got = image_relmse(out, ref)
    assert isinstance(got, float)
    assert got == pytest.approx(metric_relmse(out, ref), rel=1e-12)

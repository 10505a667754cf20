"""Augmenting crops with motion vectors (issue 37): a warp along the augmented motion of the
augmented image is the augmented warp, for every flip and rotation."""

from __future__ import annotations

import torch

from mcdenoise.filters.warp import warp
from mcdenoise.train.patches import augment


def test_warp_commutes_with_flips_and_rotations() -> None:
    g = torch.Generator().manual_seed(0)
    n, h = 16, 12
    img = torch.rand(n, 3, h, h, generator=g)
    motion = torch.empty(n, 2, h, h)
    motion[:, 0] = 1.7  # a fractional, non-symmetric displacement
    motion[:, 1] = -0.6
    motion += 0.3 * torch.rand(n, 2, h, h, generator=g)
    warped, valid = warp(img, motion)
    batch = {"img": img, "motion": motion, "warped": warped, "valid": valid}
    out = augment(batch, torch.Generator().manual_seed(3), vector_keys=["motion"])
    again, valid2 = warp(out["img"], out["motion"])
    assert torch.equal(valid2, out["valid"])
    assert torch.allclose(again, out["warped"], atol=1e-5)
    # the draws covered flips and rotations (16 crops: 16 transforms of 8)
    assert not torch.equal(out["motion"][:, 0], motion[:, 0])


def test_without_vector_keys_the_motion_is_moved_but_not_turned() -> None:
    motion = torch.zeros(8, 2, 4, 4)
    motion[:, 0] = 1.0
    out = augment({"motion": motion}, torch.Generator().manual_seed(0))
    assert torch.equal(out["motion"], motion)  # a constant field: only its pixels move

"""The temporal kpcn's own disocclusion test (issue 37): a neighbour frame's pixel is read
only where its surface is frame t's surface, with or without the renderer's motion_valid."""

from __future__ import annotations

import torch

from mcdenoise.filters.svgf_guides import make_guides
from mcdenoise.prep.kpcn_temporal import PreparedFrame, warp_window

H, W = 24, 32


def _frame(occluder_x: int, motion_dx: int | None, seed: int) -> PreparedFrame:
    """A background plane at depth 10 and a square occluder at depth 2 whose left edge is at
    ``occluder_x``; ``motion_dx``: the occluder's motion to the previous frame (pixels),
    ``None``: no motion buffer. No ``motion_valid`` (as Blender Cycles files)."""
    g = torch.Generator().manual_seed(seed)
    occ = torch.zeros(1, 1, H, W, dtype=torch.bool)
    occ[..., 6:18, occluder_x : occluder_x + 8] = True
    depth = torch.where(occ, 2.0, 10.0)
    normal = torch.zeros(1, 3, H, W)
    normal[:, 2] = 1.0
    colour = torch.where(occ, 0.2, 0.8).expand(1, 3, H, W) * (
        1 + 0.2 * torch.rand(1, 3, H, W, generator=g)
    )
    motion = None
    if motion_dx is not None:
        motion = torch.zeros(1, 2, H, W)
        motion[:, 0] = torch.where(occ[:, 0], float(motion_dx), 0.0)
    return PreparedFrame(
        {"color": colour, "depth": depth}, motion, None, guides=make_guides(depth, normal, colour)
    )


def test_disoccluded_pixels_get_no_weight_from_the_previous_frame() -> None:
    prev = _frame(8, None, 0)
    cur = _frame(12, -4, 1)  # the occluder moved 4 px right
    tens, masks, _ = warp_window([prev, cur], 1, [-1, 0])
    mask = masks[0][0, 0]
    disoccluded = mask[6:18, 8:12]  # background now, the occluder's place in frame t-1
    assert float(disoccluded.max()) == 0.0
    assert float(mask[6:18, 13:19].min()) == 1.0  # the occluder itself, followed along its motion
    assert float(mask[:, 22:].min()) == 1.0 and float(mask[:4].min()) == 1.0  # static background
    # what was read is the right surface: the occluder's colour on the occluder, 0 (unread)
    # on the disoccluded background
    assert torch.all(tens[0]["depth"][0, 0, 6:18, 13:19] == 2.0)
    assert torch.all(tens[0]["color"][..., 6:18, 8:12] == 0)


def test_without_depth_and_normal_the_warp_trusts_the_motion_as_before() -> None:
    prev, cur = _frame(8, None, 0), _frame(12, -4, 1)
    prev.guides = cur.guides = None
    _, masks, _ = warp_window([prev, cur], 1, [-1, 0])
    assert float(masks[0][0, 0, 6:18, 8:12].min()) == 1.0  # the old behaviour: blended in


def test_a_translating_camera_keeps_its_history() -> None:
    """A static scene seen by a camera moving 3 px per frame: every pixel whose source is on
    the film stays valid (no false disocclusion from the test)."""
    y, x = torch.meshgrid(
        torch.arange(H, dtype=torch.float32), torch.arange(W, dtype=torch.float32), indexing="ij"
    )
    frames = []
    for t in range(3):
        depth = (5.0 + 0.05 * (x + 3 * t) + 0.02 * y)[None, None]  # a tilted plane, in world x
        normal = torch.nn.functional.normalize(torch.tensor([-0.05, -0.02, 1.0]), dim=0)
        normal = normal[None, :, None, None].expand(1, 3, H, W).contiguous()
        colour = torch.rand(1, 3, H, W, generator=torch.Generator().manual_seed(t))
        motion = torch.zeros(1, 2, H, W)
        motion[:, 0] = 3.0  # the pixel came from 3 px to the right in the previous frame
        frames.append(
            PreparedFrame(
                {"color": colour},
                motion if t else None,
                None,
                guides=make_guides(depth, normal, colour),
            )
        )
    _, masks, _ = warp_window(frames, 2, [-2, -1, 0])
    assert float(masks[1][0, 0, :, : W - 4].min()) == 1.0
    assert float(masks[0][0, 0, :, : W - 7].min()) == 1.0
    assert float(masks[1][0, 0, :, W - 2 :].max()) == 0.0  # off the film

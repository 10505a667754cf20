"""Inputs of the temporal kpcn: a frame's prepared tensors and motion, and windows of frames
warped to the centre frame.

:func:`prepare_frame` is :func:`~mcdenoise.prep.kpcn.prepare_tensors` (the single-frame
model's inputs) plus the frame's motion buffers. :func:`warp_window` brings the frames
``t + o`` of a window onto frame ``t``'s pixel grid by chaining one-frame backward warps
(:func:`mcdenoise.filters.warp.warp`, bilinear, Falcor's tap pattern):

* a past frame ``t − d`` is warped to ``t − d + 1`` along that frame's ``motion`` (masked by
  its ``motion_valid``), then on to ``t``: ``d`` warps, each reading only pixels that were
  valid after the previous one (``source_valid``), so a pixel of frame ``t`` is valid only
  when its whole chain of surfaces was visible;
* a future frame ``t + d`` the same way along ``motion_next`` / ``motion_next_valid`` of
  frames ``t + d − 1 … t``;
* a frame without the motion buffer it needs (a cut, or a file without motion) makes the
  frames beyond it invalid everywhere (mask 0): the history is dropped;
* the method's own disocclusion test (issue 37): where both frames of a step have depth
  and normal, a bilinear tap is read only when the surface there is the destination
  pixel's surface, SVGF's ``isReprjValid`` (depth within 10 screen-space depth slopes plus
  1 % of the depth, normal within 16 normal slopes;
  :func:`mcdenoise.filters.svgf_history.consistent_taps`). A file with motion but no
  ``motion_valid`` (Blender Cycles writes none) thus no longer blends disoccluded background
  or a moving object's old place into frame ``t``; where ``motion_valid`` is present both
  must pass.

Every warped tensor is 0 where its mask is 0, never NaN (the warp never reads an invalid tap).
Frames outside the sequence are left out (``fill=False``, inference) or given as zeros with a
zero mask (``fill=True``, the fixed-size windows of training).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from mcdenoise.filters.svgf_guides import Guides, SvgfSettings, make_guides
from mcdenoise.filters.svgf_history import consistent_taps
from mcdenoise.filters.warp import warp
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.prep.kpcn import DEFAULT_PREFILTER, prepare_tensors

#: Motion buffers a frame may carry (to the previous frame, to the next one).
MOTION_BUFFERS = ("motion", "motion_valid", "motion_next", "motion_next_valid")


@dataclass
class PreparedFrame:
    """One frame: prepared tensors ``{name: (1, C, H, W)}``, its motion (``(1, 2, H, W)``
    vectors and ``(1, 1, H, W)`` masks, ``None`` when absent) and the raw depth and normal
    of its disocclusion test (``guides``; ``None`` without depth and normal)."""

    tensors: dict[str, Tensor]
    motion: Tensor | None = None
    motion_valid: Tensor | None = None
    motion_next: Tensor | None = None
    motion_next_valid: Tensor | None = None
    guides: Guides | None = None

    @property
    def size(self) -> tuple[int, int]:
        h, w = self.tensors["color"].shape[-2:]
        return int(h), int(w)


def _opt(b: FeatureBuffers, name: str, device: torch.device | str) -> Tensor | None:
    t = b.get(name)
    return None if t is None else t.to(device=device, dtype=torch.float32)[None]


def prepare_frame(
    buffers: FeatureBuffers,
    source: str,
    prefilter: str = DEFAULT_PREFILTER,
    device: torch.device | str = "cpu",
) -> PreparedFrame:
    """The kpcn inputs of ``buffers`` for ``source``, its motion buffers and the guides of
    the disocclusion test (batch of 1)."""
    t = {k: v[None].to(device) for k, v in prepare_tensors(buffers, source, prefilter).items()}
    return PreparedFrame(
        t, *(_opt(buffers, n, device) for n in MOTION_BUFFERS), guides=frame_guides(buffers, device)
    )


#: The disocclusion test's tolerances: SVGF's (Falcor's ``isReprjValid``).
DISOCCLUSION = SvgfSettings()


def frame_guides(buffers: FeatureBuffers, device: torch.device | str = "cpu") -> Guides | None:
    """Raw depth and normal of ``buffers`` as the :class:`~mcdenoise.filters.svgf_guides.
    Guides` of the disocclusion test (non-finite values as 0: no hit), or ``None`` when
    either is missing."""
    depth, normal = _opt(buffers, "depth", device), _opt(buffers, "normal", device)
    if depth is None or normal is None:
        return None
    depth, normal = torch.nan_to_num(depth[:, :1]), torch.nan_to_num(normal[:, :3])
    return make_guides(depth, normal, normal)


def _pack(t: Mapping[str, Tensor]) -> tuple[Tensor, list[tuple[str, int]]]:
    names = [(k, int(v.shape[1])) for k, v in t.items()]
    return torch.cat(list(t.values()), dim=1), names


def _unpack(x: Tensor, names: Sequence[tuple[str, int]]) -> dict[str, Tensor]:
    out, c = {}, 0
    for k, n in names:
        out[k] = x[:, c : c + n]
        c += n
    return out


def warp_to_centre(frames: Sequence[PreparedFrame], src: int, dst: int) -> tuple[Tensor, Tensor]:
    """Frame ``src``'s tensors (packed in their dict order) on frame ``dst``'s grid and the
    validity mask ``(1, 1, H, W)`` (see the module docstring)."""
    x, _ = _pack(frames[src].tensors)
    return warp_image(frames, x, src, dst)


def warp_image(
    frames: Sequence[PreparedFrame], x: Tensor, src: int, dst: int
) -> tuple[Tensor, Tensor]:
    """``x`` ``(1, C, H, W)``, an image on frame ``src``'s grid (its tensors, or a recurrent
    model's output of that frame), warped to frame ``dst`` along the frames' motion with the
    disocclusion test, and the validity mask (see the module docstring)."""
    mask = torch.ones_like(x[:, :1])
    step = 1 if src < dst else -1
    j = src
    while j != dst:
        j += step
        g = frames[j]  # the destination frame holds the vectors to its neighbour
        motion, valid = (
            (g.motion, g.motion_valid) if step == 1 else (g.motion_next, g.motion_next_valid)
        )
        if motion is None:
            return torch.zeros_like(x), torch.zeros_like(mask)
        motion = motion.to(x.dtype)
        here, there = g.guides, frames[j - step].guides
        same = (
            None
            if here is None or there is None
            else consistent_taps(here, there, motion, DISOCCLUSION)
        )
        x, mask = warp(x, motion, valid=valid, source_valid=mask, tap_valid=same)
    return x, mask


def warp_window(
    frames: Sequence[PreparedFrame], t: int, offsets: Sequence[int], *, fill: bool = False
) -> tuple[list[dict[str, Tensor]], list[Tensor], int]:
    """The window of frame ``t``: per offset, the tensors warped to frame ``t`` and their mask.

    Returns ``(tensors, masks, centre)``: ``centre`` is the index of frame ``t`` in the lists.
    Offsets outside ``frames`` are left out, or with ``fill`` zeros under a zero mask.
    """
    centre_t = frames[t].tensors
    _, names = _pack(centre_t)
    out_t: list[dict[str, Tensor]] = []
    out_m: list[Tensor] = []
    centre = -1
    for o in offsets:
        j = t + o
        if o == 0:
            centre = len(out_t)
            out_t.append(dict(centre_t))
            out_m.append(torch.ones_like(centre_t["color"][:, :1]))
            continue
        if not 0 <= j < len(frames):
            if fill:
                out_t.append({k: torch.zeros_like(v) for k, v in centre_t.items()})
                out_m.append(torch.zeros_like(centre_t["color"][:, :1]))
            continue
        x, mask = warp_to_centre(frames, j, t)
        out_t.append(_unpack(x, names))
        out_m.append(mask)
    return out_t, out_m, centre


__all__ = [
    "DISOCCLUSION",
    "MOTION_BUFFERS",
    "PreparedFrame",
    "frame_guides",
    "prepare_frame",
    "warp_image",
    "warp_to_centre",
    "warp_window",
]

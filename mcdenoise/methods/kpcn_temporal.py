"""The ``kpcn-temporal`` method: Vogels et al. 2018's temporal kernel predictor over a sequence.

A temporal method (:attr:`~mcdenoise.method.Method.temporal`): ``run_sequence`` reads the
frames of one sequence in order, prepares each once (the single-frame kpcn's inputs,
:func:`~mcdenoise.prep.kpcn_temporal.prepare_frame`), keeps the frames its window needs and
denoises frame ``t`` from the window warped to it
(:func:`~mcdenoise.prep.kpcn_temporal.warp_window`,
:class:`~mcdenoise.models.kpcn_temporal.TemporalKpcn`). In the default ``offline`` mode the window
holds past and future frames, so frame ``t`` is yielded once frame ``t + window // 2`` has
been read; ``mode=causal`` uses past frames only (interactive use: each frame is yielded as
soon as it is read). ``window`` (default: the model's) may be changed at inference; the
shipped model was trained with 5 (offline).

A recurrent model (card ``recurrent``, e.g. the shipped ``kpcn-temporal-causal``) also reads
its own previous output, warped to frame ``t`` with the same disocclusion test
(:func:`~mcdenoise.prep.kpcn_temporal.warp_image`); a cut (no motion) or a disoccluded pixel
starts it afresh there.

Frames without motion are cuts: the frames beyond them in the window are dropped (mask 0),
so a still image or a one-frame sequence gives the single-frame kpcn's result (bit for bit:
:meth:`~mcdenoise.models.kpcn_temporal.TemporalKpcn.denoise_window`). ``motion_valid`` = 0 keeps a
pixel from reading the previous frame (disocclusions). ``mcdenoise denoise`` refuses a
sequence whose frames have no motion at all for a temporal method before it gets here. All
frames of a sequence must have one size and the buffers of one input source.

Exposure (``exposure=auto``): one factor for the whole sequence, from its first frame
(:func:`~mcdenoise.prep.kpcn.exposure_scale`), so the scaling itself cannot flicker.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Iterator, Mapping
from typing import Any

import torch
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.filters.settings import GUIDE_FEATURES, GUIDE_VARS
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.method import Method, check_choice, check_frame_size
from mcdenoise.methods._learned import missing_weights, model_path, source_needs
from mcdenoise.models.encoders import SOURCES
from mcdenoise.models.kpcn_temporal import TILE, TemporalKpcn, window_offsets
from mcdenoise.models.weights import SHIPPED, load_kpcn_temporal, shipped_model_path
from mcdenoise.prep.kpcn import (
    DEFAULT_PREFILTER,
    EXPOSURE_MODES,
    PREFILTER_MODES,
    exposure_scale,
    source_for,
)
from mcdenoise.prep.kpcn_temporal import (
    MOTION_BUFFERS,
    PreparedFrame,
    prepare_frame,
    warp_image,
    warp_window,
)

NAME = "kpcn-temporal"


def _scaled(frame: PreparedFrame, k: float) -> PreparedFrame:
    if k == 1.0:
        return frame
    t = dict(frame.tensors)
    t["color"] = t["color"] * k
    if "color_var" in t:
        t["color_var"] = t["color_var"] * (k * k)
    return dataclasses.replace(frame, tensors=t)


@torch.no_grad()
def denoise_kpcn_temporal_sequence(
    model: TemporalKpcn,
    frames: Iterable[FeatureBuffers],
    *,
    window: int = 0,
    mode: str = "",
    source: str | None = None,
    prefilter: str = DEFAULT_PREFILTER,
    exposure: str = "auto",
    tile: int = TILE,
    device: torch.device | str = "cpu",
) -> Iterator[Tensor]:
    """The temporal kpcn over the frames of one sequence, in order: one ``(3, H, W)`` float32
    output per frame (linear HDR, finite, >= 0), yielded as soon as its window is complete.

    Args:
        window, mode: the window (0 / ``""``: the model's card).
        source: force an input source (default: chosen on the first frame).
        prefilter, exposure: as :func:`mcdenoise.methods.kpcn.denoise_kpcn`.
    """
    offsets = window_offsets(window or model.card.window, mode or model.card.mode)
    recurrent = model.recurrence is not None
    # a recurrent model warps its previous output along frame t's motion: keep frame t - 1
    past, future = max(-min(offsets), int(recurrent)), max(offsets)
    kept: dict[int, PreparedFrame] = {}
    size: tuple[int, int] | None = None
    src = source
    k = 1.0
    last: list[Tensor] = []  # a recurrent model's previous output (exposure-scaled)

    def output(t: int) -> Tensor:
        lo, hi = max(0, t - past), min(max(kept) + 1, t + future + 1)
        seq = [kept[j] for j in range(lo, hi)]
        tens, masks, centre = warp_window(seq, t - lo, offsets)
        prev = prev_mask = None
        if recurrent and last and t > lo:
            prev, prev_mask = warp_image(seq, last[0], t - 1 - lo, t - lo)
        out = model.denoise_window(
            tens, masks, centre, str(src), tile=tile, previous=prev, previous_mask=prev_mask
        )
        last[:] = [out] if recurrent else []
        out = out[0]
        return out / k if k != 1.0 else out

    n = 0
    for index, b in enumerate(frames):
        if src is None:
            src = source_for(b, model.base.card.sources)
            if src not in model.base.card.sources:
                raise InputError(f"{NAME}: the model has no '{src}' source")
        b.require(list(SOURCES[src]), needed_by=f"method '{NAME}' (source '{src}', frame {index})")
        size = check_frame_size(NAME, index, b.shape, size)
        frame = prepare_frame(b, src, prefilter, device)
        if index == 0 and exposure == "auto":
            k = exposure_scale(frame.tensors["color"])
        kept[index] = _scaled(frame, k)
        n = index + 1
        t = index - future
        if t >= 0:
            yield output(t)
            kept.pop(t - past, None)
    for t in range(max(0, n - future), n):
        yield output(t)
        kept.pop(t - past, None)


#: The shipped variant ``-p mode=causal`` loads (a recurrent causal model), when installed.
CAUSAL = "causal"


def _model(params: Mapping[str, Any]) -> TemporalKpcn:
    missing = f"{NAME}: no shipped weights in this install; pass -p model=RUN"
    variant = CAUSAL if str(params.get("mode", "")) == "causal" else None
    return load_kpcn_temporal(model_path(NAME, params, missing, variant))


def _check(b: FeatureBuffers, params: Mapping[str, Any]) -> str | None:
    if reason := missing_weights(NAME, params):
        return reason
    return source_needs(b, _model(params).base.card.sources)


def _run_sequence(
    frames: Iterable[FeatureBuffers], params: Mapping[str, Any], device: torch.device
) -> Iterator[Tensor]:
    model = _model(params).to(device)
    prefilter = check_choice(NAME, "prefilter", str(params["prefilter"]), PREFILTER_MODES)
    exposure = check_choice(NAME, "exposure", str(params["exposure"]), EXPOSURE_MODES)
    window, mode = int(params["window"]), str(params["mode"])
    window_offsets(window or model.card.window, mode or model.card.mode)  # one-line error now
    source = str(params["source"])
    return denoise_kpcn_temporal_sequence(
        model,
        frames,
        window=window,
        mode=mode,
        source=None if source == "auto" else source,
        prefilter=prefilter,
        exposure=exposure,
        tile=int(params["tile"]),
        device=device,
    )


METHOD = Method(
    name=NAME,
    summary="temporal kernel-predicting CNN over a window of motion-warped frames (Vogels "
    "2018); -p mode=causal: past frames and its own previous output only (recurrent), "
    "-p window=N, -p model=RUN",
    requires=("color", "albedo", "normal"),
    uses=("color_var", *GUIDE_FEATURES, *GUIDE_VARS, *MOTION_BUFFERS),
    defaults={
        "model": SHIPPED,
        "window": 0,
        "mode": "",
        "source": "auto",
        "prefilter": DEFAULT_PREFILTER,
        "exposure": "auto",
        "tile": TILE,
    },
    run=None,
    check_input=_check,
    priority=2 if shipped_model_path(NAME).is_file() else -1,
    temporal=True,
    # its first frame is kpcn's computation bit for bit: kpcn's record
    recorded_speed={NAME: (0.0189, 1.48)},
    run_sequence=_run_sequence,
)

__all__ = ["METHOD", "denoise_kpcn_temporal_sequence"]

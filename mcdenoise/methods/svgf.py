"""The ``svgf`` method: spatiotemporal variance-guided filtering over a sequence.

A temporal method (:attr:`~mcdenoise.method.Method.temporal`): ``run_sequence`` keeps the
history of :class:`~mcdenoise.filters.svgf.Svgf` from one frame to the next (the algorithm,
its Falcor reference and the deviations are in :mod:`mcdenoise.filters.svgf`). Its
parameters are :class:`~mcdenoise.filters.svgf_guides.SvgfSettings`.

Buffers: it requires only ``color`` and uses ``albedo`` (demodulation), ``depth`` and
``normal`` (edge-stopping and the reprojection tests), ``motion`` and ``motion_valid``, and
``color_var`` (steers the warm-up filter; a deviation from Falcor explained in
:mod:`mcdenoise.filters.svgf`).
SVGF is designed for a rasteriser's noise-free G-buffer; a path tracer's first-hit albedo
and normal are averages over the pixel's samples, noisy wherever those samples see
different surfaces (textures, silhouettes, depth of field), and the albedo's noise comes back
in full at remodulation, independently on every frame. So ``albedo`` and ``normal`` are
prefiltered by the preparation layer's variance-normalised NLM when their ``_var`` buffers
are present (``prefilter``: ``fast`` = 3×3 patches in a 7×7 window, the default; ``full`` =
the classical filters' 7×7 in 11×11; ``off``). Chosen on frame 0 of the demo experiment's
``caustics_glass``, ``dof_row`` and ``textured_floors`` (128², 4 spp; relMSE geometric mean
0.072 off, 0.049 fast, 0.059 full); on the sequences of ``docs/results/temporal.md`` it
lowers svgf's temporal relMSE by 11-53 %. Depth is used raw (a prefilter would blur the
silhouettes that its background test relies on).

**Frames without motion are cuts.** A frame without a ``motion`` buffer starts a new
history: it is denoised as frame 0 is (the spatial variance estimate and the à-trous
filter, no temporal accumulation). So a still image, or a sequence of one frame, works and
gives SVGF's first-frame result; a sequence whose files have no motion is filtered frame by
frame without flicker reduction (``mcdenoise denoise`` refuses such a sequence for a
temporal method before it gets here). ``motion_valid`` = 0 drops the history of those
pixels, everywhere for a cut. Frames of one sequence must share one size (else a one-line
``InputError``).

Never the default (priority 5, below ``nlm``, which accepts every input ``svgf`` accepts).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from typing import Any

import torch
from torch import Tensor

from mcdenoise.filters.parallel import single_threaded_ops
from mcdenoise.filters.svgf import Svgf
from mcdenoise.filters.svgf_guides import SvgfSettings, with_overrides
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.method import Method, check_choice, check_frame_size, dataclass_defaults
from mcdenoise.prep.inputs import PREFILTER, PREFILTER_ESTIMATED, prefilter_feature

#: Buffers the method reads when present.
USES = (
    "color_var",
    "albedo",
    "normal",
    "depth",
    "motion",
    "motion_valid",
    "albedo_var",
    "normal_var",
)
#: ``prefilter`` choices: NLM settings of the guide prefilter (``off``: raw guides).
PREFILTERS = {"off": None, "fast": PREFILTER_ESTIMATED, "full": PREFILTER}


def _guide(b: FeatureBuffers, name: str, dev: torch.device, prefilter: str) -> Tensor | None:
    """``name`` (albedo or normal) as ``(1, C, H, W)``, prefiltered by variance-normalised NLM
    with its ``_var`` buffer when it has one and ``prefilter`` is not ``off``."""
    t = _tensor(b, name, dev)
    var = _tensor(b, name + "_var", dev)
    settings = PREFILTERS[prefilter]
    if t is None or var is None or settings is None:
        return t
    return prefilter_feature(t, var, settings)


def _tensor(b: FeatureBuffers, name: str, device: torch.device) -> Tensor | None:
    t = b.get(name)
    return None if t is None else t.to(device=device, dtype=torch.float32).unsqueeze(0)


def denoise_svgf_sequence(
    frames: Iterable[FeatureBuffers],
    device: torch.device | str = "cpu",
    **overrides: object,
) -> Iterator[Tensor]:
    """SVGF over the frames of one sequence, in order: one ``(3, H, W)`` float32 output per
    frame, yielded as soon as it is done (keyword overrides replace fields of
    :class:`SvgfSettings`).

    Example:
        >>> fb = FeatureBuffers({"color": torch.full((3, 8, 8), 0.5)})
        >>> [tuple(o.shape) for o in denoise_svgf_sequence([fb, fb])]
        [(3, 8, 8), (3, 8, 8)]
    """
    dev = torch.device(device)
    options = dict(overrides)
    prefilter = check_choice("svgf", "prefilter", str(options.pop("prefilter", "fast")), PREFILTERS)
    svgf = Svgf(with_overrides(SvgfSettings(), options))
    size: tuple[int, int] | None = None
    for index, b in enumerate(frames):
        b.require(["color"], needed_by="method 'svgf'")
        size = check_frame_size("svgf", index, b.shape, size)
        with single_threaded_ops(), torch.no_grad():
            color = _tensor(b, "color", dev)
            assert color is not None
            out = svgf.step(
                color,
                albedo=_guide(b, "albedo", dev, prefilter),
                depth=_tensor(b, "depth", dev),
                normal=_guide(b, "normal", dev, prefilter),
                motion=_tensor(b, "motion", dev),
                motion_valid=_tensor(b, "motion_valid", dev),
                color_var=_tensor(b, "color_var", dev),
            )
        yield out[0]


def _run_sequence(
    frames: Iterable[FeatureBuffers], params: Mapping[str, Any], device: torch.device
) -> Iterator[Tensor]:
    return denoise_svgf_sequence(frames, device, **params)


METHOD = Method(
    name="svgf",
    summary="spatiotemporal variance-guided filtering over a sequence (Schied 2017, Falcor)",
    requires=("color",),
    uses=USES,
    defaults={**dataclass_defaults(SvgfSettings), "prefilter": "fast"},
    run=None,
    priority=5,
    temporal=True,
    run_sequence=_run_sequence,
    recorded_speed={"svgf": (0.049, 5.19)},  # the first frame (spatial à-trous only)
)

__all__ = ["METHOD", "USES", "denoise_svgf_sequence"]

"""The learned prefilter of the albedo and normal (``kpcn -p prefilter=learned``, issue 34).

:func:`learned_prefilter` runs :class:`~mcdenoise.models.auxnet.AuxNet` (the shipped weights
``models/weights/auxnet.pt`` unless a model is given) on an image's noisy albedo and normal,
tile by tile so that a 4K image needs no more memory than a 1 MP one, and returns them
filtered. :func:`learned_aux` is what ``kpcn -p prefilter=learned`` uses: the net's albedo and
normal where the pixel mixes surfaces, the adaptive NLM elsewhere and for depth and position.
The colour the net sees is brought to the standard exposure first
(:func:`mcdenoise.prep.inputs.exposure_scale`, the one ``kpcn`` uses), as the trainer
(:mod:`mcdenoise.train.auxnet`) showed it. How the weights were made:
``data/recipes/auxnet.md``; what it buys: ``docs/results/aux-prefilter.md``.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
import torch.nn.functional as F
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.models.auxnet import KINDS, AuxNet, net_inputs
from mcdenoise.models.weights import load_auxnet, shipped_model_path
from mcdenoise.prep.aux_prefilter import mixing_mask, prefilter_aux
from mcdenoise.prep.inputs import estimate_feature_variance, exposure_scale

#: Tile edge (pixels of output) and context on each side: the U-Net's receptive field is
#: about 2 · (2 + 4 + 8) + the kernel radius, so 32 pixels of context give every output
#: pixel the same inputs as a whole-image pass (to float rounding); the tile origins are
#: multiples of the net's pooling factor, so its average pools see the same blocks.
TILE = 512
CONTEXT = 32


def shipped_auxnet() -> AuxNet:
    """The shipped weights (cached).

    Raises:
        InputError: this install has none.
    """

    path = shipped_model_path("auxnet")
    if not path.is_file():
        raise InputError("prefilter=learned: no shipped auxnet weights in this install")
    return load_auxnet(path)


def noise_channels(albedo: Tensor, color: Tensor, color_var: Tensor) -> tuple[Tensor, Tensor]:
    """The colour's relative standard deviation of the mean and the albedo's standard
    deviation estimated from its neighbourhood, each ``(B, 1, H, W)`` (inputs of the net)."""
    lum = color.clamp_min(0).mean(dim=1, keepdim=True)
    color_noise = color_var.clamp_min(0).mean(dim=1, keepdim=True).sqrt() / (lum + 0.01)
    return color_noise, estimate_feature_variance(albedo).clamp_min(0).sqrt()


def prefilter_inputs(
    features: Mapping[str, Tensor],
    variances: Mapping[str, Tensor],
    color: Tensor,
    color_var: Tensor,
) -> Tensor:
    """:func:`~mcdenoise.models.auxnet.net_inputs` of an image (float32, ``features``'
    device); the variances are used only when both the albedo and the normal have one."""
    albedo = features["albedo"].float()
    normal = features["normal"].float().to(albedo.device)
    av, nv = variances.get("albedo"), variances.get("normal")
    if av is None or nv is None:
        av = nv = None
    else:
        av, nv = av.to(albedo), nv.to(albedo)
    col = color.to(albedo)
    cn, an = noise_channels(albedo, col, color_var.to(albedo))
    return net_inputs(albedo, normal, col * exposure_scale(col), cn, an, av, nv)


@torch.no_grad()
def learned_prefilter(
    features: Mapping[str, Tensor],
    variances: Mapping[str, Tensor],
    color: Tensor,
    color_var: Tensor,
    model: AuxNet | None = None,
    *,
    tile: int = TILE,
) -> dict[str, Tensor]:
    """The albedo and normal of ``features`` filtered by the net; ``{}`` without both.

    Args:
        features: name -> ``(1, C, H, W)`` sanitised feature (albedo and normal as written).
        variances: name -> ``(1, 1 or C, H, W)`` variance of the mean, for those that have one
            (used only when both the albedo and the normal have one, as in training).
        color, color_var: ``(1, 3, H, W)`` sanitised linear colour and ``(1, 1, H, W)`` its
            variance of the mean (the renderer's or the estimate).
        model: the net (default :func:`shipped_auxnet`).
        tile: output tile edge (rounded up to the net's pooling factor).
    """
    if not all(k in features and features[k].shape[1] == c for k, c in KINDS.items()):
        return {}
    net = model if model is not None else shipped_auxnet()
    param = next(net.parameters())
    x = prefilter_inputs(features, variances, color, color_var).to(param.device, param.dtype)
    albedo = features["albedo"].to(param.device, torch.float32)
    normal = features["normal"].to(param.device, torch.float32)
    m = net.multiple
    tile = max(m, -(-tile // m) * m)
    ctx = -(-CONTEXT // m) * m
    h, w = x.shape[-2:]
    out_a = torch.empty_like(albedo)
    out_n = torch.empty_like(normal)
    for y0 in range(0, h, tile):
        for x0 in range(0, w, tile):
            y1, x1 = min(y0 + tile, h), min(x0 + tile, w)
            ya, xa = max(0, y0 - ctx), max(0, x0 - ctx)
            yb, xb = min(h, y1 + ctx), min(w, x1 + ctx)
            ph, pw = (-(yb - ya)) % m, (-(xb - xa)) % m
            crop = x[..., ya:yb, xa:xb]
            if ph or pw:
                crop = F.pad(crop, (0, pw, 0, ph), mode="replicate")
            weights = net(crop)[..., : yb - ya, : xb - xa]
            bufs = {"albedo": albedo[..., ya:yb, xa:xb], "normal": normal[..., ya:yb, xa:xb]}
            filt = net.filter(weights, bufs)
            sy, sx = slice(y0 - ya, y1 - ya), slice(x0 - xa, x1 - xa)
            out_a[..., y0:y1, x0:x1] = filt["albedo"][..., sy, sx]
            out_n[..., y0:y1, x0:x1] = filt["normal"][..., sy, sx]
    dtype = features["albedo"].dtype
    device = features["albedo"].device
    return {"albedo": out_a.to(device, dtype), "normal": out_n.to(device, dtype)}


def learned_aux(
    features: Mapping[str, Tensor],
    variances: Mapping[str, Tensor],
    color: Tensor,
    color_var: Tensor,
    model: AuxNet | None = None,
) -> dict[str, Tensor]:
    """Every feature as ``kpcn -p prefilter=learned`` prepares it: the net's albedo and normal
    in the pixels that mix surfaces (:func:`~mcdenoise.prep.aux_prefilter.mixing_mask`: the
    raw normal is short), the adaptive NLM (:func:`~mcdenoise.prep.aux_prefilter.prefilter_aux`)
    everywhere else and for the other features.

    Why not the net everywhere: trained on the random scenes, it smooths texture finer than a
    pixel as if it were noise (``ood_fine_texture``: kpcn 0.40× OIDN's relMSE at 4 spp with
    the adaptive prefilter, 1.32× with the net everywhere), while where the samples of a pixel
    saw different surfaces (a defocused edge, thin emitters on a dark road) it is what the
    hand-tuned filter is not (``docs/results/aux-prefilter.md``).
    """
    out = prefilter_aux(features, variances, color, color_var)
    learned = learned_prefilter(features, variances, color, color_var, model)
    if learned:
        mixing = mixing_mask(features["normal"])
        for name, value in learned.items():
            out[name] = torch.where(mixing, value.to(out[name]), out[name])
    return out


__all__ = [
    "CONTEXT",
    "TILE",
    "learned_aux",
    "learned_prefilter",
    "shipped_auxnet",
]

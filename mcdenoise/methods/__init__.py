"""The built-in denoising methods: one adapter module per method, listed by :func:`builtin_methods`.

=================  ==========================================================  ========
name               what                                                        priority
=================  ==========================================================  ========
kpcn               kernel-predicting U-Net (Bako 2017) with source-aware           35
                   encoders and 3-scale kernels (Vogels 2018); ``model`` = a run
                   folder or model file, default the shipped weights
                   (:mod:`~mcdenoise.methods.kpcn`; -1 without shipped weights)
kalantari-xbf      two-pass cross-bilateral filter whose per-pixel bandwidths      30
                   a small MLP predicts from local features (Kalantari 2015);
                   ``model`` = a run folder or model file, default the shipped
                   weights (:mod:`~mcdenoise.methods.kalantari`)
kalantari-nlm      the same learning for NLM (per-pixel k and feature k_f)         25
nlm                variance-normalised non-local means with feature weights    20
                   (Rousselle 2012/2013), albedo-demodulated
                   (:mod:`~mcdenoise.methods.nlm`)
cross-bilateral    cross-bilateral filter with Kalantari 2015 terms, fixed     10
                   default bandwidths (alias ``xbf``;
                   :mod:`~mcdenoise.methods.cross_bilateral`)
svgf               temporal: spatiotemporal variance-guided filtering          5
                   (Schied 2017; Falcor's SVGFPass) over a sequence with
                   motion vectors; a frame without motion is a cut, so a
                   still gets the first-frame filter (:mod:`~mcdenoise.methods.svgf`)
nfor               NFOR (Bitterli 2016): first-order regression on the          3
                   features with NL-means weights across the two half buffers,
                   bandwidth chosen per pixel by the two-buffer error; needs
                   ``color_a``/``color_b`` (:mod:`~mcdenoise.methods.nfor`)
kpcn-temporal      temporal: Vogels 2018 kernel predictor over a window of      2
                   motion-warped frames (5, offline; ``-p window``,
                   ``-p mode=causal``) around the shipped kpcn; a one-frame
                   sequence is kpcn bit for bit
                   (:mod:`~mcdenoise.methods.kpcn_temporal`; -1 without weights)
oidn               Intel Open Image Denoise (pyoidn), colour + albedo +        0
                   normal; a peer to compare with, never the default
                   (:mod:`~mcdenoise.methods.oidn`)
ssao, hbao,        AO estimators: screen-space ambient occlusion from depth,  -10
alchemy, gtao,     normal and the recorded camera (Crytek; Bavoil 2008;
nnao               McGuire 2011/2012; Jimenez 2016 after XeGTAO; Holden 2016's
                   learned NNAO); they ignore the noisy colour and compete with
                   ray-traced AO plus a denoiser (:mod:`~mcdenoise.methods.ao`,
                   :mod:`~mcdenoise.methods.nnao`)
=================  ==========================================================  ========

Each module builds its :class:`~mcdenoise.method.Method` (buffers -> :mod:`mcdenoise.prep` ->
filter or model -> output) without registering it; :mod:`mcdenoise.registry` adds
:func:`builtin_methods` to its table on first use, so the listing never depends on which
module happened to be imported first.

The default method (no ``--method``) is the first available one, by priority, that accepts
the input (:meth:`~mcdenoise.method.Method.accepts`: the buffers it requires, then its own
``check_input``; :func:`mcdenoise.registry.choose_method`). kpcn ranks first whenever its
shipped weights are installed: it needs colour, albedo and normal and uses whatever else the
input has (the ``full`` source with every feature variance, the ``basic`` one without). Out
of the training distribution it is the best of the project's methods at 4 and 16 spp, and the only
one within the 4K bounds (issue 21; ``docs/results/ood.md``, ``docs/results/kalantari.md``
"4K"); kalantari-xbf, next, is better on the four sample renders at 16 spp and the user's
choice when time does not matter. The Kalantari models accept an input only with every
guide *and guide variance* their model was trained with (the shipped models: albedo, normal,
depth, position and their variances; kalantari-xbf serves inputs without albedo with its
shipped no-albedo variant); they do not estimate missing variances (a file without them has
no per-sample information, and an estimate from the image would be outside their training
data). So an input without albedo goes to kalantari-xbf when it has the other guides and
their variances, else to nlm, which runs on colour alone; ``mcdenoise denoise --verbose``
prints every method passed over and why. OIDN is deliberately never the default: mcdenoise's
own methods are what it reports on, OIDN is the baseline they are compared with. The
measurements behind this order are in ``docs/results/methods-notes.md``.
"""

from __future__ import annotations

from mcdenoise.method import Method
from mcdenoise.methods import (
    ao,
    cross_bilateral,
    kalantari,
    kpcn,
    kpcn_temporal,
    nfor,
    nlm,
    nnao,
    oidn,
    svgf,
)


def builtin_methods() -> list[tuple[Method, tuple[str, ...]]]:
    """Every built-in method with its aliases, in a fixed order."""
    return [
        (nlm.METHOD, ()),
        (cross_bilateral.METHOD, cross_bilateral.ALIASES),
        (kalantari.XBF, ()),
        (kalantari.NLM, ()),
        (kpcn.METHOD, ()),
        (oidn.METHOD, ()),
        (svgf.METHOD, ()),
        (nfor.METHOD, ()),  # NFOR, needs half buffers (issue 24, H4)
        (kpcn_temporal.METHOD, ()),  # temporal KPCN (Vogels 2018; issue 23, H2)
        *((m, ()) for m in ao.METHODS),  # AO estimators (issue 25, H5)
        (nnao.METHOD, ()),  # learned AO estimator (Holden 2016; issue 25, H7)
    ]


__all__ = ["builtin_methods"]

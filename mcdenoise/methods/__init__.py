"""The built-in denoising methods: one adapter module per method, listed by :func:`builtin_methods`.

The methods, what each is and its priority: ``docs/methods.md`` (the table at its top and
"Choosing a method"); ``mcdenoise methods`` lists them with the buffers each needs.

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
one within the 4K bounds (``docs/results/ood.md``, ``docs/results/kalantari.md``
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
        (nfor.METHOD, ()),  # NFOR, needs half buffers
        (kpcn_temporal.METHOD, ()),  # temporal KPCN (Vogels 2018)
        *((m, ()) for m in ao.METHODS),  # AO estimators
        (nnao.METHOD, ()),  # learned AO estimator (Holden 2016)
    ]


__all__ = ["builtin_methods"]

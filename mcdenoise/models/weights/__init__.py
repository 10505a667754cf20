"""Shipped model weights and a cached loader.

``kalantari-xbf.pt`` (245 scenes), ``kalantari-nlm.pt`` and ``kalantari-xbf-noalbedo.pt``
(the first 120 of them) were trained by the commands in ``data/recipes/kalantari.md`` on
``mcdenoise render`` data (seed 1000) that no reported evaluation uses. ``kpcn-temporal.pt``
and ``kpcn-temporal-causal.pt`` (the temporal kpcn around ``kpcn.pt``, offline and recurrent
causal): ``data/recipes/kpcn-temporal.md``. ``kpcn.pt`` and
``kpcn-learned.pt`` (the variant ``kpcn -p prefilter=learned`` loads): ``data/recipes/kpcn.md``;
``auxnet.pt`` (that prefilter): ``data/recipes/auxnet.md``. ``nnao.pt``: ``data/recipes/nnao.md``. :func:`load_kalantari` accepts a model file or a run folder (its
``model.pt``) and caches the loaded model per file and modification time.
"""

from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path

from mcdenoise.modelfile import CheckpointError, model_file, read_card
from mcdenoise.models.auxnet import FORMAT as AUXNET_FORMAT
from mcdenoise.models.auxnet import AuxNet
from mcdenoise.models.kalantari import KalantariModel
from mcdenoise.models.kpcn import FORMAT as KPCN_FORMAT
from mcdenoise.models.kpcn import KpcnModel
from mcdenoise.models.kpcn_temporal import FORMAT as TEMPORAL_FORMAT
from mcdenoise.models.kpcn_temporal import TemporalKpcn
from mcdenoise.models.nnao import FORMAT as NNAO_FORMAT

WEIGHTS = Path(__file__).resolve().parent
#: ``model`` parameter value of the learned methods meaning "the weights shipped here".
SHIPPED = "shipped"


#: Suffix of the shipped variant trained without albedo (for AO renders and other inputs
#: that have no albedo buffer).
NO_ALBEDO = "noalbedo"


def shipped_model_path(name: str, variant: str = "") -> Path:
    """Path of the shipped weights of model ``name`` (e.g. ``kalantari-xbf``), or of a variant."""
    return WEIGHTS / (f"{name}-{variant}.pt" if variant else f"{name}.pt")


def shipped_model_for(name: str, buffers_present: set[str]) -> Path:
    """The shipped weights of ``name`` for an input holding ``buffers_present``: the main
    model, or the no-albedo variant when the input has no albedo and that variant exists."""
    variant = shipped_model_path(name, NO_ALBEDO)
    if "albedo" not in buffers_present and variant.is_file():
        return variant
    return shipped_model_path(name)


@functools.lru_cache(maxsize=64)
def _file_digest(path: str, mtime_ns: int, size: int) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


def weights_digest(method: str, model: str) -> str:
    """Content hash of the weights ``method`` loads for its ``model`` parameter: ``"shipped"``
    (the shipped file and its variants) or a model file / run folder. Experiment caches key on
    it, so retrained or updated weights never reuse a result made with others. Files that do
    not exist hash as ``missing``."""
    if model in ("", SHIPPED):
        paths = [shipped_model_path(method), *sorted(WEIGHTS.glob(f"{method}-*.pt"))]
    else:
        paths = [Path(model)]
    parts = []
    for path in paths:
        try:
            p = model_file(path)
        except CheckpointError:
            parts.append("missing")
            continue
        st = p.stat()
        parts.append(_file_digest(str(p.resolve()), st.st_mtime_ns, st.st_size))
    return ",".join(parts)


@functools.lru_cache(maxsize=8)
def _load(
    path: str, mtime_ns: int, kind: str
) -> KalantariModel | KpcnModel | TemporalKpcn | AuxNet:
    if kind == "auxnet":
        return AuxNet.load(path)
    if kind == "kpcn-temporal":
        return TemporalKpcn.load(path)
    return KpcnModel.load(path) if kind == "kpcn" else KalantariModel.load(path)


def load_kalantari(path: str | os.PathLike[str]) -> KalantariModel:
    """The Kalantari model in ``path`` (a model file or a run folder), cached.

    Raises:
        CheckpointError: no such file/folder, or a truncated file. InputError: not a model
        of a compatible feature set (the message names the difference).
    """
    p = model_file(path)
    return _load(str(p.resolve()), p.stat().st_mtime_ns, "kalantari")  # type: ignore[return-value]


def load_kpcn(path: str | os.PathLike[str]) -> KpcnModel:
    """The kpcn model in ``path`` (a model file or a run folder), cached (same errors)."""
    p = model_file(path)
    return _load(str(p.resolve()), p.stat().st_mtime_ns, "kpcn")  # type: ignore[return-value]


def load_kpcn_temporal(path: str | os.PathLike[str]) -> TemporalKpcn:
    """The temporal kpcn model in ``path`` (a model file or a run folder), cached (same
    errors as :func:`load_kalantari`)."""
    p = model_file(path)
    return _load(str(p.resolve()), p.stat().st_mtime_ns, "kpcn-temporal")  # type: ignore[return-value]


def load_auxnet(path: str | os.PathLike[str]) -> AuxNet:
    """The auxiliary-buffer prefilter in ``path`` (a model file or a run folder), cached (same
    errors as :func:`load_kalantari`)."""
    p = model_file(path)
    return _load(str(p.resolve()), p.stat().st_mtime_ns, "auxnet")  # type: ignore[return-value]


def model_method(path: str | os.PathLike[str]) -> str:
    """The method a model file belongs to: ``kpcn``, ``kpcn-temporal``, ``nnao``,
    ``kalantari-xbf`` or ``kalantari-nlm``."""
    card = read_card(path)
    if card.get("format") == KPCN_FORMAT:
        return "kpcn"
    if card.get("format") == TEMPORAL_FORMAT:
        return "kpcn-temporal"
    if card.get("format") == NNAO_FORMAT:
        return "nnao"
    if card.get("format") == AUXNET_FORMAT:
        return "auxnet"
    return f"kalantari-{card.get('kind', 'xbf')}"

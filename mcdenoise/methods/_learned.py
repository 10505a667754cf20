"""What the learned kpcn methods (``kpcn``, ``kpcn-temporal``) share around their networks:
where the model comes from (``-p model``: the shipped weights or a run folder / model file)
and the input checks before a run (shipped weights present, a source the model was trained
with). Not a method itself: nothing here is registered.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from mcdenoise.errors import InputError
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.models.encoders import SOURCES
from mcdenoise.models.weights import SHIPPED, shipped_model_path
from mcdenoise.prep.kpcn import choose_source

#: Why a learned method cannot run without ``-p model`` in an install without its weights.
NO_WEIGHTS = "no shipped weights in this install (pass -p model=RUN_FOLDER)"


def is_shipped(params: Mapping[str, Any]) -> bool:
    """Whether ``-p model`` names the shipped weights (its default)."""
    return str(params["model"]) in ("", SHIPPED)


def model_path(
    name: str, params: Mapping[str, Any], missing: str, variant: str | None = None
) -> str | Path:
    """The model file ``-p model`` names for method ``name``: the shipped weights (its
    ``variant`` when given and shipped), or the run folder / file as given; ``missing`` is the
    ``InputError`` message when the shipped weights are not installed."""
    if not is_shipped(params):
        return str(params["model"])
    path = shipped_model_path(name)
    if variant is not None and shipped_model_path(name, variant).is_file():
        path = shipped_model_path(name, variant)
    if not path.is_file():
        raise InputError(missing)
    return path


def missing_weights(name: str, params: Mapping[str, Any]) -> str | None:
    """:data:`NO_WEIGHTS` when ``-p model`` is the shipped weights and they are not installed
    (the method's ``check_input`` then says so before anything is loaded); else ``None``."""
    if is_shipped(params) and not shipped_model_path(name).is_file():
        return NO_WEIGHTS
    return None


def source_needs(b: FeatureBuffers, wanted: Iterable[str]) -> str | None:
    """``None`` when ``b`` has the buffers of one of the ``wanted`` input sources (those the
    model was trained with); else the reason, naming what each source misses."""
    wanted = list(wanted)
    if choose_source(set(b.buffers), wanted) is not None:
        return None
    needs = " or ".join(
        f"{s} ({', '.join(x for x in SOURCES[s] if x not in b)})" for s in wanted if s in SOURCES
    )
    return f"needs the buffers of a source the model was trained with: {needs}"


__all__ = ["NO_WEIGHTS", "is_shipped", "missing_weights", "model_path", "source_needs"]

"""Model files and checkpoints on disk: ``torch.save`` of a dict, read with ``weights_only=True``.

A *model file* (what ``--model`` / ``-p model=`` loads) is::

    {"card": {format, ...},   plain JSON types only: what is needed to rebuild the module
     "state": state_dict}     the weights

where ``card`` is the model's own card (:class:`~mcdenoise.models.kalantari.ModelCard`,
:class:`~mcdenoise.models.kpcn.KpcnCard`) as a dict and its ``format`` names the model family
and layout version. A *run folder* of ``mcdenoise train`` holds its exported model as
``model.pt`` (:func:`model_file` resolves either). Training checkpoints are other dicts written
and read with the same two functions (:func:`save_state`, :func:`load_state`).

Every file is written atomically (:func:`mcdenoise.io.atomic.atomic_path`) and read without
running pickled code; a missing, truncated or foreign file is a :class:`CheckpointError` whose
one-line message names it. This module sits below :mod:`mcdenoise.models` and
:mod:`mcdenoise.train`, which both use it.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from mcdenoise.errors import InputError, McdenoiseError
from mcdenoise.io.atomic import atomic_path

#: File name of the exported model inside a run folder.
RUN_MODEL = "model.pt"


class CheckpointError(McdenoiseError, OSError):
    """A model file, run folder or checkpoint is missing, truncated or not ours."""


def load_state(path: str | os.PathLike[str]) -> dict[str, Any]:
    """``torch.load(path, weights_only=True)``, errors turned into one-line CheckpointErrors."""
    p = Path(path)
    if not p.is_file():
        raise CheckpointError(f"{p}: no such checkpoint/model file")
    try:
        state = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises RuntimeError, EOFError, UnpicklingError, ...
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise CheckpointError(f"{p}: truncated or corrupt file ({first})") from None
    if not isinstance(state, dict):
        raise CheckpointError(f"{p}: not an mcdenoise checkpoint (no state dictionary)")
    return state


def save_state(state: dict[str, Any], path: str | os.PathLike[str]) -> None:
    """``torch.save`` atomically."""
    with atomic_path(path) as tmp:
        torch.save(state, tmp)


def model_file(path: str | os.PathLike[str]) -> Path:
    """The model file ``path`` names: itself, or a run folder's ``model.pt``.

    Raises:
        CheckpointError: neither exists.
    """
    p = Path(path)
    if p.is_dir():
        p = p / RUN_MODEL
    if not p.is_file():
        raise CheckpointError(f"{path}: no such model file or run folder (with {RUN_MODEL})")
    return p


def read_model_file(path: str | os.PathLike[str]) -> tuple[Path, dict[str, Any]]:
    """``(file, state)`` of a model file or a run folder's ``model.pt``: a dict with a JSON
    ``card`` and the weights ``state``.

    Raises:
        CheckpointError: missing/truncated file, or a file without a model card.
    """
    p = Path(path)
    if p.is_dir():
        p = p / RUN_MODEL
    state = load_state(p)
    if "card" not in state or "state" not in state:
        raise CheckpointError(f"{p}: not a model file (no model card)")
    return p, state


def read_card(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The card (a dict) of the model file ``path`` (a file or a run folder)."""
    p, state = read_model_file(model_file(path))
    card = state["card"]
    if not isinstance(card, dict):
        raise CheckpointError(f"{p}: not a model file (no model card)")
    return card


def json_card(card: Mapping[str, Any]) -> dict[str, Any]:
    """``card`` with plain JSON types only (what ``weights_only`` loading accepts)."""
    return json.loads(json.dumps(card))


def save_model(card: Mapping[str, Any], module: torch.nn.Module, path: str | os.PathLike[str]):
    """Write the model file ``{"card": card, "state": module's weights on the CPU}`` atomically."""
    state = {k: v.detach().cpu() for k, v in module.state_dict().items()}
    save_state({"card": json_card(card), "state": state}, path)


def load_weights(module: torch.nn.Module, state: dict[str, Any], path: Path) -> None:
    """``module.load_state_dict(state)``; a mismatch is a one-line InputError naming ``path``."""
    try:
        module.load_state_dict(state)
    except RuntimeError as err:
        first = str(err).splitlines()[0]
        raise InputError(f"{path}: weights do not match the model card ({first})") from None


__all__ = [
    "RUN_MODEL",
    "CheckpointError",
    "json_card",
    "load_state",
    "load_weights",
    "model_file",
    "read_card",
    "read_model_file",
    "save_model",
    "save_state",
]

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
one-line message names it (a pickle of Python objects reads "not a model file (refused: it
holds Python objects)", with none of torch's advice to load it with ``weights_only=False``).

A card comes from a file that may come from anyone, so the models read its fields through
:class:`CardFields` (type and range of every field, one line naming the file and the field)
and bound the size of the module it describes with :func:`check_model_size` before building
it: ``hidden = [1e5, 1e5]`` asked for 40 GB, ``kernel = 100001`` for 1 TB.

Every model shares the plumbing through two bases: its dataclass card derives from
:class:`Card` (``to_dict``, the format check of ``from_dict``) and its module from
:class:`CardModule` (``save``, ``load``); only the field reads of ``from_dict`` are the model's.

This module sits below :mod:`mcdenoise.models` and :mod:`mcdenoise.train`, which both use it.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import os
import pickle
import pickletools
import re
import warnings
import zipfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar, NoReturn, Self

import torch

from mcdenoise.errors import InputError, McdenoiseError
from mcdenoise.io.atomic import atomic_path

#: File name of the exported model inside a run folder.
RUN_MODEL = "model.pt"

# Bounds of a model card read from a file, far above every model trained here (the largest
# shipped one, kpcn-temporal, has 0.32 M parameters, 64 channels, 5×5 kernels): a card from
# elsewhere must not make the tool allocate without limit.
#: Parameters (and buffers) of the module a card describes: 80 MB of float32.
MAX_PARAMETERS = 20_000_000
#: Channels (units) of one layer: also bounds the activations of a tile.
MAX_WIDTH = 1024
#: Hidden layers of an MLP, levels of a U-Net.
MAX_LAYERS = 16
#: Edge of a predicted per-pixel kernel (k² weights per pixel of a strip).
MAX_KERNEL = 41
#: Length of any other list in a card (names, statistics).
MAX_ITEMS = 1024

_MISSING: Any = object()


class CheckpointError(McdenoiseError, OSError):
    """A model file, run folder or checkpoint is missing, truncated or not ours."""


class CardFields:
    """Typed, bounded reads of the fields of a model card (a dict from a file).

    Each reader returns the field's value (or ``default`` when the field is absent and a
    default is given) or raises an :class:`InputError` whose one line names the file and the
    field: ``m.pt: model card field 'hidden[0]': 100000 is out of range (1 to 1024)``. Integers
    may be stored as integral floats (``1e5``); a bool is not a number.

    >>> CardFields({"kernel": 5}, "m.pt").integer("kernel", 1, MAX_KERNEL, odd=True)
    5
    >>> CardFields({"hidden": [32, 1e5]}, "m.pt").integers("hidden", 1, MAX_WIDTH)
    Traceback (most recent call last):
    ...
    mcdenoise.errors.InputError: m.pt: model card field 'hidden[1]': 100000 is out of range (1 to 1024)
    """

    def __init__(self, card: object, what: str, prefix: str = "") -> None:
        if not isinstance(card, Mapping):
            where = f" field '{prefix}'" if prefix else ""
            raise InputError(f"{what}: model card{where} is not a dictionary")
        self.card = card
        self.what = what
        self.prefix = prefix

    def fail(self, key: str, problem: str) -> NoReturn:
        """Raise the InputError of ``key`` (a field name, ``name[i]`` for an item)."""
        name = f"{self.prefix}.{key}" if self.prefix else key
        raise InputError(f"{self.what}: model card field '{name}': {problem}")

    def sub(self, key: str, default: Any = _MISSING) -> CardFields:
        """The fields of the dict in field ``key``."""
        name = f"{self.prefix}.{key}" if self.prefix else key
        return CardFields(self.get(key, default), self.what, name)

    def get(self, key: str, default: Any = _MISSING) -> Any:
        """The raw value of ``key``; an absent field without a default is an error."""
        if key in self.card:
            return self.card[key]
        if default is _MISSING:
            self.fail(key, "missing")
        return default

    def _int(self, key: str, v: Any, lo: int, hi: int, odd: bool) -> int:
        if isinstance(v, float) and math.isfinite(v) and v.is_integer():
            v = int(v)
        if isinstance(v, bool) or not isinstance(v, int):
            self.fail(key, f"must be an integer, got {_short(v)}")
        if not lo <= v <= hi:
            self.fail(key, f"{v} is out of range ({lo} to {hi})")
        if odd and v % 2 == 0:
            self.fail(key, f"must be odd, got {v}")
        return v

    def _number(self, key: str, v: Any, lo: float, hi: float) -> float:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(key, f"must be a number, got {_short(v)}")
        v = float(v)
        if math.isnan(v) or not lo <= v <= hi:
            self.fail(key, f"{v} is out of range ({lo} to {hi})")
        return v

    def _text(self, key: str, v: Any, choices: Sequence[str] | None) -> str:
        if not isinstance(v, str) or len(v) > 200:
            self.fail(key, f"must be a short string, got {_short(v)}")
        if choices is not None and v not in choices:
            self.fail(key, f"{v!r} is not one of {', '.join(choices)}")
        return v

    def _list(self, key: str, min_len: int, max_len: int, default: Any) -> list[Any]:
        v = self.get(key, default)
        if not isinstance(v, (list, tuple)):
            self.fail(key, f"must be a list, got {_short(v)}")
        if not min_len <= len(v) <= max_len:
            self.fail(key, f"must have {min_len} to {max_len} items, got {len(v)}")
        return list(v)

    def integer(
        self, key: str, lo: int, hi: int, *, odd: bool = False, default: Any = _MISSING
    ) -> int:
        """An integer in ``[lo, hi]`` (odd if asked)."""
        return self._int(key, self.get(key, default), lo, hi, odd)

    def number(
        self, key: str, lo: float = -math.inf, hi: float = math.inf, *, default: Any = _MISSING
    ) -> float:
        """A number (int or float, not NaN) in ``[lo, hi]``."""
        return self._number(key, self.get(key, default), lo, hi)

    def flag(self, key: str, *, default: Any = _MISSING) -> bool:
        """A bool."""
        v = self.get(key, default)
        if not isinstance(v, bool):
            self.fail(key, f"must be true or false, got {_short(v)}")
        return v

    def text(
        self, key: str, choices: Sequence[str] | None = None, *, default: Any = _MISSING
    ) -> str:
        """A string (one of ``choices`` if given)."""
        return self._text(key, self.get(key, default), choices)

    def integers(
        self,
        key: str,
        lo: int,
        hi: int,
        *,
        min_len: int = 1,
        max_len: int = MAX_LAYERS,
        default: Any = _MISSING,
    ) -> list[int]:
        """A list of ``min_len`` to ``max_len`` integers in ``[lo, hi]``."""
        items = self._list(key, min_len, max_len, default)
        return [self._int(f"{key}[{i}]", v, lo, hi, False) for i, v in enumerate(items)]

    def numbers(
        self,
        key: str,
        lo: float = -math.inf,
        hi: float = math.inf,
        *,
        min_len: int = 0,
        max_len: int = MAX_ITEMS,
        default: Any = _MISSING,
    ) -> list[float]:
        """A list of numbers in ``[lo, hi]``."""
        items = self._list(key, min_len, max_len, default)
        return [self._number(f"{key}[{i}]", v, lo, hi) for i, v in enumerate(items)]

    def texts(
        self,
        key: str,
        choices: Sequence[str] | None = None,
        *,
        min_len: int = 0,
        max_len: int = MAX_ITEMS,
        unique: bool = False,
        default: Any = _MISSING,
    ) -> list[str]:
        """A list of strings (each one of ``choices`` if given; no repeats if ``unique``)."""
        items = self._list(key, min_len, max_len, default)
        out = [self._text(f"{key}[{i}]", v, choices) for i, v in enumerate(items)]
        if unique and len(set(out)) != len(out):
            self.fail(key, f"repeats a name: {out}")
        return out

    def mapping(self, key: str, *, default: Any = _MISSING) -> dict[str, Any]:
        """A dict with string keys (free-form values, e.g. ``training``)."""
        v = self.get(key, default)
        if not isinstance(v, Mapping) or not all(isinstance(k, str) for k in v):
            self.fail(key, f"must be a dictionary, got {_short(v)}")
        return dict(v)


def _short(v: Any) -> str:
    """``v`` for a message: its repr, cut to 40 characters, and its type."""
    text = repr(v)
    text = text if len(text) <= 40 else text[:37] + "..."
    return f"{text} ({type(v).__name__})"


def check_model_size(
    build: Callable[[], torch.nn.Module], what: str, limit: int = MAX_PARAMETERS
) -> int:
    """The number of parameters and buffers of the module ``build()`` makes, counted on
    torch's ``meta`` device (shapes only, nothing allocated); more than ``limit`` is an
    InputError naming ``what``. Call it on a card from a file before building the real module.
    """
    with torch.device("meta"):
        module = build()
    n = sum(t.numel() for t in itertools.chain(module.parameters(), module.buffers()))
    if n > limit:
        raise InputError(
            f"{what}: the model card describes a model of {n:,} parameters, more than the "
            f"{limit:,} a model file may have"
        )
    return n


#: Pickle opcodes that name or build a Python object (a class, a function to call).
_OBJECT_OPCODES = frozenset(
    {"GLOBAL", "STACK_GLOBAL", "INST", "OBJ", "NEWOBJ", "NEWOBJ_EX", "REDUCE", "BUILD", "EXT1"}
    | {"EXT2", "EXT4"}
)
#: Bytes of pickle data scanned to tell a pickle of objects from a damaged file.
_SCAN_BYTES = 64 * 2**20


def _pickle_streams(p: Path) -> Iterator[bytes]:
    """The pickle data of a file: each ``.pkl`` record of a zip (torch's format), else the
    file's first bytes (a legacy torch file or a plain pickle)."""
    try:
        if zipfile.is_zipfile(p):
            with zipfile.ZipFile(p) as z:
                for info in z.infolist():
                    if info.filename.endswith(".pkl") and info.file_size <= _SCAN_BYTES:
                        yield z.read(info)
            return
        with p.open("rb") as f:
            yield f.read(_SCAN_BYTES)
    except (OSError, zipfile.BadZipFile, RuntimeError, ValueError):
        return


def _pickle_kind(p: Path) -> str | None:
    """``"objects"`` if the pickle data of ``p`` (up to five pickles one after the other, as
    in a legacy torch file) names or builds Python objects, ``"plain"`` if it parses and does
    not, ``None`` if it is not pickle data. Only parsed (pickletools), never unpickled."""
    kind = None
    for data in _pickle_streams(p):
        pos = 0
        for _ in range(5):
            if pos >= len(data):
                break
            try:
                ops = list(pickletools.genops(data[pos:]))
            except Exception:  # not (or no longer) pickle data
                break
            if any(op.name in _OBJECT_OPCODES for op, _, _ in ops):
                return "objects"
            kind = "plain"
            pos += (ops[-1][2] or 0) + 1
    return kind


def _load_refusal(p: Path, err: Exception) -> str:
    """The one-line message of a file ``torch.load(weights_only=True)`` refused, without torch's
    advice to load it with ``weights_only=False`` (which would run the file's code)."""
    text = re.sub(r"\x1b\[[0-9;]*m", "", str(err)).strip()
    if isinstance(err, pickle.UnpicklingError):
        kind = "objects" if "Unsupported global" in text else _pickle_kind(p)
        if kind == "objects":
            return f"{p}: not a model file (refused: it holds Python objects)"
        if kind == "plain" and not zipfile.is_zipfile(p):
            return f"{p}: not a model file (a plain pickle, not written by torch.save)"
    detail = re.search(r"WeightsUnpickler error:\s*(\S[^\n]*)", text)
    if detail:
        first = detail.group(1).strip()
    else:
        first = text.splitlines()[0] if text else type(err).__name__
    if "weights_only" in first or "Weights only" in first:
        first = "not pickle data torch can read"
    # torch's own request for reports ("(Could this error message be improved? ...)")
    first = re.sub(r"\s*\(?Could this error message be improved\?.*$", "", first) or "?"
    return f"{p}: truncated or corrupt file ({first})"


def load_state(path: str | os.PathLike[str]) -> dict[str, Any]:
    """``torch.load(path, weights_only=True)``, errors turned into one-line CheckpointErrors.

    Only a regular file is opened (a named pipe would wait forever). torch's warnings about
    the file's pickle protocol are not shown; a refused file is described in our terms
    (:func:`_load_refusal`).
    """
    p = Path(path)
    if not p.is_file():
        if p.exists() and not p.is_dir():
            raise CheckpointError(f"{p}: not a regular file (a pipe or a device); refused")
        raise CheckpointError(f"{p}: no such checkpoint/model file")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            state = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises RuntimeError, EOFError, UnpicklingError, ...
        raise CheckpointError(_load_refusal(p, err)) from None
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
        if p.exists():
            raise CheckpointError(f"{p}: not a regular file (a pipe or a device); refused")
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
    if not isinstance(state, Mapping) or not all(
        isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in state.items()
    ):
        raise InputError(f"{path}: not a model file (its weights are not a dict of tensors)")
    try:
        module.load_state_dict(state)
    except RuntimeError as err:
        lines = [ln.strip() for ln in str(err).splitlines() if ln.strip()]
        # torch's first line is a heading ("Error(s) in loading state_dict for X:"); the
        # next says what differs (missing or unexpected keys, a shape mismatch)
        detail = " ".join(lines[:2])[:300]
        raise InputError(f"{path}: weights do not match the model card ({detail})") from None


class Card:
    """Base of the dataclass model cards: the JSON round trip and the format check.

    A subclass is a ``@dataclass`` whose last field is ``format: str = FORMAT`` (the model
    family and layout version) and whose ``from_dict(d, what)`` reads every field through
    :meth:`fields` (:class:`CardFields`: type and range) and bounds the module's size
    (:func:`check_model_size`) before returning the card.
    """

    def plain(self) -> dict[str, Any]:
        """The card's fields as a dict (nested dataclasses as dicts); a card adds derived
        fields here."""
        return dataclasses.asdict(self)  # type: ignore[call-overload]

    def to_dict(self) -> dict[str, Any]:
        """The card as written to a model file: plain JSON types only (``weights_only``)."""
        return json_card(self.plain())

    @classmethod
    def fields(cls, d: object, what: str) -> CardFields:
        """The :class:`CardFields` of ``d``, a card read from ``what``, after checking that its
        ``format`` is this card's (an InputError naming both otherwise)."""
        expected = cls.__dataclass_fields__["format"].default  # type: ignore[attr-defined]
        f = CardFields(d, what)
        if f.get("format", None) != expected:
            raise InputError(f"{what}: format {f.get('format', None)!r} is not {expected!r}")
        return f

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], what: str = "model file") -> Self:
        """The card of a model file, every field checked (each card defines it)."""
        raise NotImplementedError


class CardModule(torch.nn.Module):
    """Base of the models with a card: ``save`` writes the model file, ``load`` reads one.

    A subclass sets :attr:`card_class`, is built by ``cls(card)`` and keeps the card as
    ``self.card``; a model whose construction needs more (a check naming the file) overrides
    :meth:`from_card`.
    """

    card_class: ClassVar[type[Card]]
    card: Any

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the model file atomically."""
        save_model(self.card.to_dict(), self, path)

    @classmethod
    def from_card(cls, card: Any, path: Path) -> Self:
        """The untrained module of ``card`` (read from ``path``)."""
        return cls(card)  # type: ignore[call-arg]

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Self:
        """Read a model file (or a run folder's ``model.pt``), in eval mode.

        Raises:
            CheckpointError: missing/truncated file. InputError: not a model of this kind, a
            card field out of range, or weights that do not match the card.
        """
        p, state = read_model_file(path)
        model = cls.from_card(cls.card_class.from_dict(state["card"], what=str(p)), p)
        load_weights(model, state["state"], p)
        model.eval()
        return model


__all__ = [
    "MAX_ITEMS",
    "MAX_KERNEL",
    "MAX_LAYERS",
    "MAX_PARAMETERS",
    "MAX_WIDTH",
    "RUN_MODEL",
    "Card",
    "CardFields",
    "CardModule",
    "CheckpointError",
    "check_model_size",
    "json_card",
    "load_state",
    "load_weights",
    "model_file",
    "read_card",
    "read_model_file",
    "save_model",
    "save_state",
]

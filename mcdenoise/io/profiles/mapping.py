"""The ``mapping`` profile: a user mapping file (TOML or JSON) that names channels directly.

Its entries override the detected or forced profile for the buffers they list, and are
required to be present; with no profile detected, only the mapped buffers are read::

    color = ["beauty.R", "beauty.G", "beauty.B"]
    albedo = ["alb.R", "alb.G", "alb.B"]
    color_var = ["var.Y"]
    spp = 64
    variance = "sample"   # *_var channels hold the per-sample variance: divided by spp

See :func:`load_mapping` for the keys and their checks.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcdenoise.io.buffers import BUFFER_NAMES, VAR_SUFFIX, expected_channels
from mcdenoise.io.profiles.base import Alternatives, Profile, ProfileError


@dataclass(frozen=True)
class ChannelMapping:
    """A user mapping: buffer -> file channels, plus optional ``spp`` and variance kind."""

    buffers: dict[str, tuple[str, ...]]
    spp: int | None = None
    variance: str = "mean"
    source: str = "mapping"


class MappingProfile(Profile):
    """Only what a user mapping names (used when no renderer profile applies)."""

    name = "mapping"
    description = "only the channels named by a mapping file"

    def propose(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> Alternatives:
        return {}


def _parse_mapping_text(text: str, fmt: str, where: str) -> Any:
    if fmt == "toml":
        try:
            import tomllib  # lazy: optional, see except
        except ModuleNotFoundError:  # Python 3.10
            try:
                import tomli as tomllib  # type: ignore[no-redef]  # lazy: optional, see except
            except ModuleNotFoundError:
                raise ProfileError(
                    f"{where}: reading TOML needs Python 3.11+ (or the tomli package); "
                    "use a JSON mapping file"
                ) from None
        try:
            return tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise ProfileError(f"{where}: invalid TOML: {e}") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise ProfileError(f"{where}: invalid JSON: {e.msg} (line {e.lineno})") from None


def load_mapping(mapping: str | os.PathLike[str] | Mapping[str, Any]) -> ChannelMapping:
    """Read and validate a user mapping (TOML or JSON file, or an already parsed mapping).

    Keys: buffer names (see :data:`mcdenoise.io.buffers.BUFFER_NAMES`) -> list of channel
    names, with the buffer's channel count (1 allowed for ``*_var``); optional ``spp``
    (positive int) and ``variance`` (``"mean"``: ``*_var`` channels hold the variance of the
    mean; ``"sample"``: per-sample variance, divided by ``spp`` on load).

    Raises:
        ProfileError: unreadable file, syntax error, unknown key, wrong type or channel count.
    """
    if isinstance(mapping, Mapping):
        data: Any = dict(mapping)
        where = "mapping"
    else:
        path = Path(mapping)
        where = str(path)
        if not path.is_file():
            raise ProfileError(f"{where}: mapping file not found")
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as e:
            raise ProfileError(f"{where}: cannot read mapping file ({e})") from None
        suffix = path.suffix.lower()
        if suffix == ".toml":
            data = _parse_mapping_text(text, "toml", where)
        elif suffix == ".json":
            data = _parse_mapping_text(text, "json", where)
        else:
            try:
                data = json.loads(text)
            except json.JSONDecodeError:
                data = _parse_mapping_text(text, "toml", where)
    if not isinstance(data, dict):
        raise ProfileError(f"{where}: a mapping must be a table of buffer = [channels]")
    buffers: dict[str, tuple[str, ...]] = {}
    spp = None
    variance = "mean"
    for key, value in data.items():
        if key == "spp":
            if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
                raise ProfileError(f"{where}: spp must be a positive integer, got {value!r}")
            spp = value
        elif key == "variance":
            if value not in ("mean", "sample"):
                raise ProfileError(f"{where}: variance must be 'mean' or 'sample', got {value!r}")
            variance = value
        elif key in BUFFER_NAMES:
            if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
                raise ProfileError(f"{where}: {key} must be a list of channel names, got {value!r}")
            want = expected_channels(key)
            ok = len(value) == want or (key.endswith(VAR_SUFFIX) and len(value) == 1)
            if not ok:
                allowed = f"{want}" + (" or 1" if key.endswith(VAR_SUFFIX) and want > 1 else "")
                raise ProfileError(
                    f"{where}: {key} needs {allowed} channel name(s), got {len(value)}: {value}"
                )
            buffers[key] = tuple(value)
        else:
            raise ProfileError(
                f"{where}: unknown key {key!r}; allowed: spp, variance, {', '.join(BUFFER_NAMES)}"
            )
    if not buffers:
        raise ProfileError(f"{where}: the mapping names no buffer")
    return ChannelMapping(buffers, spp, variance, where)

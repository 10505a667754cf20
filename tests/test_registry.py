"""The method table: the built-ins are there whichever module was imported first, in a fixed
order; registering replaces; lookups by alias; the contract's per-frame / temporal forms."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import torch

from mcdenoise import registry
from mcdenoise.errors import InputError
from mcdenoise.io import FeatureBuffers
from mcdenoise.method import Method

BUILTINS = {"nlm", "cross-bilateral", "kalantari-xbf", "kalantari-nlm", "kpcn", "oidn"}


def _listing(imports: str) -> list[str]:
    """The method names listed in a fresh interpreter that imports ``imports`` only."""
    code = f"{imports}\nfrom mcdenoise import registry\nimport json\n"
    code += "print(json.dumps([m.name for m in registry.methods()]))"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=300
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_listing_does_not_depend_on_what_was_imported_first() -> None:
    alone = _listing("import mcdenoise.registry")
    assert BUILTINS <= set(alone)
    assert _listing("import mcdenoise.denoise") == alone
    assert _listing("import mcdenoise.methods") == alone
    assert alone == [m.name for m in registry.methods()]


def test_get_method_knows_aliases_and_lists_the_known_ones() -> None:
    assert registry.get_method("xbf").name == "cross-bilateral"
    with pytest.raises(InputError, match=r"unknown method 'magic' \(known: .*nlm"):
        registry.get_method("magic")


def _color(b: FeatureBuffers, p: object, d: torch.device) -> torch.Tensor:
    return b["color"]


def test_register_replaces_a_builtin_and_a_stand_in_survives_loading(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    registry.methods()
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    monkeypatch.setattr(registry, "_ALIASES", dict(registry._ALIASES))  # "mine" goes with it
    mine = Method("nlm", "my nlm", ("color",), (), {}, _color, priority=99)
    registry.register(mine, aliases=("mine",))
    assert registry.get_method("nlm") is mine and registry.get_method("mine") is mine
    assert registry.methods()[0] is mine
    monkeypatch.delitem(registry._ALIASES, "mine")
    # before the built-ins are loaded, an entry already in the table keeps its place
    monkeypatch.setattr(registry, "_REGISTRY", {"nlm": mine})
    monkeypatch.setattr(registry, "_builtins", {"state": "no"})
    names = [m.name for m in registry.methods()]
    assert registry.get_method("nlm") is mine and BUILTINS <= set(names)


def test_a_per_frame_method_runs_a_sequence_frame_by_frame() -> None:
    m = Method("c", "t", ("color",), (), {}, _color)
    assert not m.temporal and m.run_sequence is None
    frames = [FeatureBuffers({"color": torch.full((3, 2, 2), float(i))}) for i in range(3)]
    outs = list(m.run_frames(frames, {}, torch.device("cpu")))
    assert [float(o[0, 0, 0]) for o in outs] == [0.0, 1.0, 2.0]

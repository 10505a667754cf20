"""The benchmark-only scene sets of issues 36 and 37 (data/scenes/textured, data/scenes/motion):
they parse, their names are their own, `mcdenoise render data/scenes` does not pick them up,
and no training recipe or package code reads them."""

from __future__ import annotations

from pathlib import Path

import pytest

from mcdenoise.render.effects import plan_effects
from mcdenoise.render.scene_spec import collect_specs, load_spec

ROOT = Path(__file__).resolve().parents[2]
SETS = {"textured": "tex_", "motion": "motion_"}


@pytest.mark.parametrize("folder", sorted(SETS))
def test_specs_parse_with_their_own_names(folder: str) -> None:
    specs = [load_spec(p) for p in sorted((ROOT / "data" / "scenes" / folder).glob("*.toml"))]
    assert len(specs) >= 2
    names = [s.name for s in specs]
    assert len(set(names)) == len(names) and all(n.startswith(SETS[folder]) for n in names)
    for s in specs:
        plan_effects(s)  # the declared effects fit the scene
    if folder == "motion":
        assert all(s.animation is not None for s in specs)


def test_they_are_evaluation_only() -> None:
    curated = collect_specs([ROOT / "data" / "scenes"])
    assert not any(p.parent.name in SETS for p in curated)
    evaluation = {"ood.md", "heldout-halves.md"}
    texts = [
        p.read_text() for p in (ROOT / "data" / "recipes").glob("*.md") if p.name not in evaluation
    ]
    texts += [p.read_text() for p in (ROOT / "mcdenoise").rglob("*.py")]
    assert not [t for t in texts if "scenes/textured" in t or "scenes/motion" in t]

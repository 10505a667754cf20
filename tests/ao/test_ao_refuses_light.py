"""The AO estimators refuse a render of light (its ``mcdenoise:effects`` has no ``ao``): they
estimate ambient occlusion from the G-buffer, and comparing that with a lit reference would
put meaningless rows in an experiment (``methods = "all"`` in the demo)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from mcdenoise.errors import InputError
from mcdenoise.io import load_buffers
from mcdenoise.methods import ao, nnao

FIXTURE = Path(__file__).resolve().parent / "ao_contact_48x36.exr"
NAMES = [m.name for m in ao.METHODS] + [nnao.METHOD.name]


@pytest.mark.parametrize("name", NAMES)
def test_a_render_of_light_is_refused_in_one_line(name: str) -> None:
    from mcdenoise.registry import get_method

    fb = load_buffers(FIXTURE)
    assert "ao" in str(fb.attributes.get("mcdenoise:effects", "ao")).split(",")
    method = get_method(name)
    assert method.accepts(fb) is None  # the AO render itself is accepted
    fb.attributes["mcdenoise:effects"] = "direct,indirect"
    reason = method.accepts(fb)
    assert reason is not None and "not of ambient occlusion" in reason and "\n" not in reason
    with pytest.raises(InputError, match="not of ambient occlusion"):
        ao.camera_for(fb, dict(method.defaults))
    assert torch.isfinite(fb["depth"]).all()

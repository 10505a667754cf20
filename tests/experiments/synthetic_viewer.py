"""Helpers of the viewer tests (``test_viewer.py``, ``test_viewer_browser.py``): a synthetic
experiment whose viewer data has every case, and the stored layers decoded in Python.

Two scenes of 36×40 at 1 and 4 spp (``alpha`` at 4 spp has a 2×2 block of NaN, as a renderer's
numerical failure leaves them); methods that agree (``box``, ``soft``), one that disagrees in
a planted 12×12 square (``odd``) and one that cannot run (``refuse``).
"""

from __future__ import annotations

import base64
import json
import re
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from synthetic_data import FakeMethods, blend, box3, make_render_folder, refuse, write_spec

from mcdenoise.experiments import load_experiment, run_experiment
from mcdenoise.io import FeatureBuffers, load_buffers, save_buffers_parts

#: The planted disagreement of ``odd``: rows 20-31, columns 24-35 (x, y, side).
PLANT = (24, 20, 12)
SIZE = (36, 40)
METHODS = ("box", "soft", "odd", "refuse")


def odd(b, p, d):
    """A box filter, far too bright in the planted square."""
    out = box3(b["color"]).clone()
    x, y, s = PLANT
    out[:, y : y + s, x : x + s] += 3.0
    return out


def add_methods(fake: FakeMethods) -> None:
    fake.add("box", blend)
    fake.add("soft", blend, defaults={"strength": 0.5})
    fake.add("odd", odd)
    fake.add("refuse", refuse)


def make_data(folder: Path) -> Path:
    """The render folder; ``alpha`` at 4 spp has NaN in its top-left 2×2 pixels."""
    make_render_folder(folder, size=SIZE, spp=(1, 4))
    path = folder / "alpha.exr"
    parts = {p: load_buffers(path, part=p) for p in ("spp1", "spp4")}
    parts["spp4"]["color"][:, :2, :2] = torch.nan
    save_buffers_parts(
        path, {p: FeatureBuffers(dict(b.buffers), spp=b.spp) for p, b in parts.items()}
    )
    return folder


def run_viewer_experiment(tmp: Path, *, outputs: str = "all") -> tuple[Path, Any]:
    """Run the experiment into ``tmp/out``; returns the folder and the result."""
    make_data(tmp / "rendered")
    spec = write_spec(
        tmp / "exp.toml",
        f'methods = {json.dumps(list(METHODS))}\nmetrics = ["relmse"]\nrepetitions = 1\n'
        'warmup = 0\n[scenes]\nfolder = "rendered"\n[stats]\nbootstrap = 100\n'
        f'[report]\nstrip_spp = 4\noutputs = "{outputs}"\n',
    )
    with pytest.MonkeyPatch.context() as mp:
        add_methods(FakeMethods(mp))
        summary = run_experiment(load_experiment(spec), tmp / "out")
    return tmp / "out", summary.result


SEQ_SPEC = """
methods = ["box"]
repetitions = 1
warmup = 0
[scenes]
folder = "{folder}"
[stats]
bootstrap = 100
[report]
strip_spp = 2
warmup_frames = 1
"""


def run_sequence_experiment(tmp: Path, fake: FakeMethods) -> Any:
    """A 3-frame 16×16 sequence at 2 and 8 spp, ``box`` on it, into ``tmp/out``; the result."""
    from synthetic_sequences import make_sequence_folder

    folder = make_sequence_folder(tmp / "render", frames=3, size=(16, 16), spp=(2, 8))
    fake.add("box")
    spec = write_spec(tmp / "seq.toml", SEQ_SPEC.format(folder=folder.as_posix()))
    return run_experiment(load_experiment(spec), tmp / "out").result


def load_scene(path: Path) -> dict[str, Any]:
    """The JSON object a ``viewer/scene_NN.js`` registers."""
    text = path.read_text(encoding="ascii")
    m = re.fullmatch(r"mcdViewerRegister\((.*)\);\n", text, flags=re.S)
    assert m is not None, text[:200]
    return json.loads(m.group(1))


def decode_f16(text: str, shape: tuple[int, ...]) -> np.ndarray:
    """base64 → zlib → low-byte plane ‖ high-byte plane → little-endian float16."""
    raw = np.frombuffer(zlib.decompress(base64.b64decode(text)), dtype=np.uint8)
    n = raw.size // 2
    values = (raw[:n].astype(np.uint16) | (raw[n:].astype(np.uint16) << 8)).view("<f2")
    return values.reshape(shape).astype(np.float32)


def decode_u8(text: str, shape: tuple[int, ...]) -> np.ndarray:
    """base64 → zlib → uint8."""
    return np.frombuffer(zlib.decompress(base64.b64decode(text)), dtype=np.uint8).reshape(shape)

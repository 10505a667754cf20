"""The ``tungsten`` profile: KPCN's Tungsten data (mcdenoise/io/profiles/tungsten.py)."""

from __future__ import annotations

import numpy as np
from profile_files import planes, stack, write

from mcdenoise.io import load_buffers


def test_tungsten_kpcn(tmp_path, rng):
    ch = planes(rng, ["R", "G", "B", "colorA.R", "colorA.G", "colorA.B", "colorVariance.Z"])
    ch.update(planes(rng, ["colorB.R", "colorB.G", "colorB.B"]))
    for layer, sfx in [("albedo", "RGB"), ("normal", "RGB"), ("diffuse", "RGB"),
                       ("specular", "RGB"), ("depth", "Z"), ("visibility", "Z")]:  # fmt: skip
        ch.update(planes(rng, [f"{layer}.{c}" for c in sfx]))
        ch.update(planes(rng, [f"{layer}A.{c}" for c in sfx]))
        ch.update(planes(rng, [f"{layer}B.{c}" for c in sfx]))
        ch.update(planes(rng, [f"{layer}Variance.Z"], 0, 0.01))
    fb = load_buffers(write(tmp_path / "t.exr", ch))
    assert fb.profile == "tungsten"
    feats = ["color", "albedo", "normal", "depth", "diffuse", "specular", "visibility"]
    halves = {f + h for f in feats for h in ("_a", "_b")}  # KPCN's two-buffer halves
    assert set(fb.names()) == set(feats) | {f + "_var" for f in feats} | halves
    np.testing.assert_array_equal(
        fb["normal"].numpy(), stack(ch, ["normal.R", "normal.G", "normal.B"])
    )
    np.testing.assert_array_equal(fb["visibility"].numpy()[0], ch["visibility.Z"])
    np.testing.assert_array_equal(fb["color_var"].numpy()[0], ch["colorVariance.Z"])  # copied
    np.testing.assert_array_equal(fb["diffuse_var"].numpy()[0], ch["diffuseVariance.Z"])

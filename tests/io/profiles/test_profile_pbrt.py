"""The ``pbrt`` profile: pbrt-v4 gbuffer film (mcdenoise/io/profiles/pbrt.py)."""

from __future__ import annotations

import numpy as np
import pytest
from profile_files import planes, stack, write

from mcdenoise.errors import InputError
from mcdenoise.io import describe, load_buffers


def test_pbrt_gbuffer(tmp_path, rng):
    names = ["R", "G", "B", "Albedo.R", "Albedo.G", "Albedo.B", "P.X", "P.Y", "P.Z", "dzdx",
             "dzdy", "N.X", "N.Y", "N.Z", "Ns.X", "Ns.Y", "Ns.Z", "u", "v", "Variance.R",
             "Variance.G", "Variance.B", "RelativeVariance.R", "RelativeVariance.G",
             "RelativeVariance.B"]  # fmt: skip
    ch = planes(rng, names)
    path = write(tmp_path / "p.exr", ch, {"samplesPerPixel": 16})
    fb = load_buffers(path)
    assert fb.profile == "pbrt" and fb.spp == 16
    assert fb.names() == ["color", "albedo", "normal", "depth", "position", "color_var"]
    np.testing.assert_array_equal(fb["normal"].numpy(), stack(ch, ["Ns.X", "Ns.Y", "Ns.Z"]))
    np.testing.assert_array_equal(fb["depth"].numpy()[0], ch["P.Z"])
    # Per-sample variance (of luminance: pbrt's sensor space is XYZ) -> variance of the mean.
    np.testing.assert_allclose(fb["color_var"].numpy()[0], ch["Variance.G"] / 16, rtol=1e-6)
    info = describe(path)
    assert {"N.X", "u", "Variance.R", "RelativeVariance.G"} <= set(info.unmapped)
    # Planar camera-space depth and camera-space position are not the canonical conventions.
    assert [n.split(":")[0] for n in info.notes] == ["depth", "position"]
    assert "planar depth" in info.notes[0] and "camera space" in info.notes[1]
    with pytest.raises(InputError, match="conflicting sample counts"):
        load_buffers(path, spp=32)

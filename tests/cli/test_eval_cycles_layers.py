"""``mcdenoise eval`` of an output made from one view layer of a Blender Cycles file (issue 21):
``denoise --profile cycles:Layer2`` (or ``--part Layer2``) records ``mcdenoise:source_profile``;
``eval`` reads the noisy row and the reference with that layer, never the first one, and a
reference without that layer is one error line naming the layer and the layers it has."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fast_methods import run_cli as run

from mcdenoise.eval import metrics as M
from mcdenoise.io import load_buffers
from mcdenoise.io.exr import probe_exr
from mcdenoise.io.exr_write import write_exr

CYCLES = Path(__file__).resolve().parents[1] / "io" / "data" / "cycles_32" / "cycles_spp4.exr"
H = W = 32


def blender_file(path: Path, layers: dict[str, np.ndarray], samples: int | None = None) -> Path:
    """A Blender-like multilayer EXR: ``<Layer>.Combined.R/G/B/A`` per layer."""
    ch: dict[str, np.ndarray] = {}
    attrs: dict[str, object] = {"BlenderMultiChannel": "Blender 5.0.1"}
    for name, rgb in layers.items():
        for i, c in enumerate("RGB"):
            ch[f"{name}.Combined.{c}"] = rgb[i]
        ch[f"{name}.Combined.A"] = np.ones_like(rgb[0])
        if samples is not None:
            attrs[f"cycles.{name}.samples"] = str(samples)
    write_exr(path, ch, attributes=attrs)
    return path


def image(seed: int, scale: float = 1.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (scale * rng.gamma(2.0, 0.4, size=(3, H, W))).astype(np.float32)


def rows(out_dir: Path) -> dict[str, dict]:
    import json

    data = json.loads((out_dir / "results.json").read_text())
    return {r["role"] + ":" + r["method"]: r for r in data["records"]}


def by_hand(image: np.ndarray, ref: np.ndarray) -> float:
    return M.compute_metrics(image, ref, ["relmse"]).values["relmse"]


def color(path: Path, **kw) -> np.ndarray:
    return load_buffers(path, **kw)["color"].numpy()


def test_second_layer_is_evaluated_against_the_references_second_layer(here):
    read = ["--profile", "cycles:Layer2"]
    noisy = blender_file(here / "noisy.exr", {"ViewLayer": image(1), "Layer2": image(2)}, 4)
    ref_first, ref_second = image(3), image(4, scale=3.0)  # the layers differ
    ref = blender_file(here / "ref.exr", {"ViewLayer": ref_first, "Layer2": ref_second})
    r = run("denoise", noisy, "-m", "box3", *read, "-o", "den.exr")
    assert r.exit_code == 0, r.output
    assert probe_exr(here / "den.exr")[0].attributes["mcdenoise:source_profile"] == "cycles:Layer2"

    r = run("eval", "--ref", ref, "den.exr", "-o", "ev", "--metrics", "relmse")
    assert r.exit_code == 0, r.output
    got = rows(here / "ev")
    den, noisy_row = got["output:box3"], got["noisy:noisy"]
    assert "Layer2" in noisy_row["file"] and den["scene"] == noisy_row["scene"] == "ref:Layer2"
    want_den = by_hand(color(here / "den.exr"), ref_second)
    want_noisy = by_hand(image(2), ref_second)
    assert den["metrics"]["relmse"] == pytest.approx(want_den, rel=1e-6)
    assert noisy_row["metrics"]["relmse"] == pytest.approx(want_noisy, rel=1e-6)
    assert noisy_row["spp"] == 4
    # against the first layers, the numbers would be others
    assert want_noisy != pytest.approx(by_hand(image(1), ref_first), rel=1e-3)
    assert want_den != pytest.approx(by_hand(color(here / "den.exr"), ref_first), rel=1e-3)


@pytest.mark.parametrize("read", [["--profile", "cycles:Layer2"], ["--part", "Layer2"]])
def test_real_cycles_file_second_layer(here, read):
    """The committed Blender 5.0.1 render (one part per pass, two view layers): the noisy row
    is its Layer2 ``Combined``, the reference's Layer2 is the one compared."""
    first = color(CYCLES, profile="cycles:ViewLayer")
    second = color(CYCLES, profile="cycles:Layer2")
    assert not np.allclose(first, second)
    ref_second = (0.5 * second + 0.2).astype(np.float32)
    ref = blender_file(here / "ref.exr", {"ViewLayer": first, "Layer2": ref_second})
    r = run("denoise", CYCLES, "-m", "box3", *read, "-o", "den.exr")
    assert r.exit_code == 0, r.output
    r = run("eval", "--ref", ref, "den.exr", "-o", "ev", "--metrics", "relmse")
    assert r.exit_code == 0, r.output
    got = rows(here / "ev")
    assert got["noisy:noisy"]["metrics"]["relmse"] == pytest.approx(
        by_hand(second, ref_second), rel=1e-6
    )
    assert got["output:box3"]["metrics"]["relmse"] == pytest.approx(
        by_hand(color(here / "den.exr"), ref_second), rel=1e-6
    )


def test_reference_without_the_layer_is_one_error_line(here):
    noisy = blender_file(here / "noisy.exr", {"ViewLayer": image(1), "Layer2": image(2)})
    ref = blender_file(here / "ref.exr", {"ViewLayer": image(3), "Other": image(5)})
    assert run("denoise", noisy, "-m", "box3", "--profile", "cycles:Layer2", "-o", "d.exr")
    r = run("eval", "--ref", ref, "d.exr", "-o", "ev")
    assert r.exit_code != 0
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1, r.output
    assert "no Cycles view layer 'Layer2'" in lines[0], lines[0]
    assert "'ViewLayer'" in lines[0] and "'Other'" in lines[0], lines[0]
    assert "Traceback" not in r.output and not (here / "ev").exists()


def test_auto_layer_is_recorded_and_a_plain_reference_is_taken_as_given(here):
    """Without a layer option the auto-detected layer is recorded too (in a single-part file
    channels are sorted: the "first" layer is Layer2 here, which a reference of another layout
    need not share); a plain RGB reference (no view layers) is one image, compared as given."""
    layers = {"ViewLayer": image(1), "Layer2": image(2)}
    noisy = blender_file(here / "noisy.exr", layers)
    auto = load_buffers(noisy).profile
    assert auto is not None and auto.startswith("cycles:")
    assert run("denoise", noisy, "-m", "box3", "-o", "d.exr").exit_code == 0
    assert probe_exr(here / "d.exr")[0].attributes["mcdenoise:source_profile"] == auto
    plain = here / "plain.exr"
    ref = image(6)
    write_exr(plain, {c: ref[i] for i, c in enumerate("RGB")})
    r = run("eval", "--ref", plain, "d.exr", "-o", "ev", "--metrics", "relmse")
    assert r.exit_code == 0, r.output
    got = rows(here / "ev")
    assert got["noisy:noisy"]["scene"] == "plain"
    want = by_hand(layers[auto.split(":", 1)[1]], ref)
    assert got["noisy:noisy"]["metrics"]["relmse"] == pytest.approx(want, rel=1e-6)


def test_plain_outputs_and_given_noisy_file_are_unchanged(here):
    """Files of no Cycles layout record no profile; the noisy file given with the outputs is
    still the noisy row (one row, not also an output)."""
    noisy, ref = here / "noisy.exr", here / "ref.exr"
    write_exr(noisy, {c: image(7)[i] for i, c in enumerate("RGB")})
    write_exr(ref, {c: image(8)[i] for i, c in enumerate("RGB")})
    assert run("denoise", noisy, "-m", "box3", "-o", "d.exr").exit_code == 0
    assert "mcdenoise:source_profile" not in probe_exr(here / "d.exr")[0].attributes
    r = run("eval", "--ref", ref, "d.exr", noisy, "-o", "ev", "--metrics", "relmse")
    assert r.exit_code == 0, r.output
    assert sorted(rows(here / "ev")) == ["noisy:noisy", "output:box3"]


def test_given_cycles_noisy_file_is_read_with_the_recorded_layer(here):
    """``eval --ref REF OUT NOISY`` with NOISY the Cycles source of OUT: one noisy row, read
    with OUT's layer (not the auto-detected one)."""
    layers = {"ViewLayer": image(1), "Layer2": image(2)}
    noisy = blender_file(here / "noisy.exr", layers)
    refs = {"ViewLayer": image(3), "Layer2": image(4, scale=2.0)}
    ref = blender_file(here / "ref.exr", refs)
    auto = load_buffers(noisy).profile.split(":", 1)[1]
    other = next(n for n in layers if n != auto)
    r = run("denoise", noisy, "-m", "box3", "--profile", f"cycles:{other}", "-o", "d.exr")
    assert r.exit_code == 0, r.output
    r = run("eval", "--ref", ref, "d.exr", noisy, "-o", "ev", "--metrics", "relmse")
    assert r.exit_code == 0, r.output
    got = rows(here / "ev")
    assert sorted(got) == ["noisy:noisy", "output:box3"]
    want = by_hand(layers[other], refs[other])
    assert got["noisy:noisy"]["metrics"]["relmse"] == pytest.approx(want, rel=1e-6)

"""``--profile`` takes what the library takes (``cycles:<Layer>`` included), a bad value is one
line listing the valid forms; the ``eval --metrics`` help lists the registered metrics;
``registry.aliases()`` is the public alias table (issues 20 and 21)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from mcdenoise_cli.main import main
from mcdenoise_cli.options import PROFILE_FORMS, profile_forms

from mcdenoise import registry
from mcdenoise.io import load_buffers
from mcdenoise.io.exr_write import write_exr
from mcdenoise.io.profiles import PROFILE_NAMES

ONE_THREAD = True
H, W = 12, 16


def run(*args: str):
    return CliRunner().invoke(main, list(args), catch_exceptions=False)


def two_layer_file(path: Path) -> Path:
    """A Blender multilayer EXR with two view layers: ``ViewLayer`` (Noisy Image, albedo,
    normal; colour about 0.5) and ``SecondLayer`` (Combined only; colour about 2)."""
    rng = np.random.default_rng(3)
    ch: dict[str, np.ndarray] = {}
    for c in "RGB":
        ch[f"ViewLayer.Combined.{c}"] = rng.uniform(0.4, 0.6, (H, W))
        ch[f"ViewLayer.Noisy Image.{c}"] = rng.uniform(0.4, 0.6, (H, W))
        ch[f"ViewLayer.Denoising Albedo.{c}"] = np.full((H, W), 0.5)
        ch[f"SecondLayer.Combined.{c}"] = rng.uniform(1.9, 2.1, (H, W))
    for c, v in zip("XYZ", (0.0, 0.0, 1.0)):
        ch[f"ViewLayer.Denoising Normal.{c}"] = np.full((H, W), v)
    attrs = {
        "BlenderMultiChannel": "Blender V2.55.1 and newer",
        "cycles.ViewLayer.samples": 4,
        "cycles.SecondLayer.samples": 16,
    }
    write_exr(path, {k: v.astype(np.float32) for k, v in ch.items()}, attributes=attrs)
    return path


def test_profile_cycles_layer_from_the_cli(tmp_path: Path) -> None:
    src = two_layer_file(tmp_path / "two.exr")
    out = tmp_path / "second.exr"
    r = run("denoise", str(src), "-o", str(out), "--profile", "cycles:SecondLayer")
    assert r.exit_code == 0, r.output
    got = load_buffers(out)
    assert got.attributes["mcdenoise:method"] == "nlm"  # the layer has colour only
    assert got.spp == 16  # the layer's own sample count
    assert abs(float(got.color.mean()) - 2.0) < 0.05
    r = run("denoise", str(src), "-o", str(tmp_path / "first.exr"), "--method", "nlm")
    assert r.exit_code == 0, r.output
    assert abs(float(load_buffers(tmp_path / "first.exr").color.mean()) - 0.5) < 0.05
    r = run("info", str(src), "--profile", "cycles:SecondLayer")
    assert r.exit_code == 0 and "cycles:SecondLayer" in r.output


@pytest.mark.parametrize(
    ("value", "needle"),
    [("renderman", "unknown profile 'renderman'"), ("mitsuba:x", "takes no option")],
)
def test_a_bad_profile_is_one_line_listing_the_valid_forms(
    tmp_path: Path, value: str, needle: str
) -> None:
    src = two_layer_file(tmp_path / "two.exr")
    r = run("denoise", str(src), "--profile", value)
    assert r.exit_code == 2
    (line,) = [x for x in r.stderr.splitlines() if x.startswith("Error:")]
    assert needle in line and f"valid forms: {PROFILE_FORMS}" in line
    assert not list(tmp_path.glob("two_*.exr"))


def test_a_layer_the_file_does_not_have_is_one_line(tmp_path: Path) -> None:
    src = two_layer_file(tmp_path / "two.exr")
    r = run("denoise", str(src), "--profile", "cycles:Nope")
    assert r.exit_code == 1
    (line,) = r.stderr.strip().splitlines()
    assert line.startswith("mcdenoise: error:") and "'Nope'" in line
    assert "'ViewLayer'" in line and "'SecondLayer'" in line


def test_the_profile_help_lists_the_library_profiles() -> None:
    assert PROFILE_FORMS == profile_forms(PROFILE_NAMES)
    help_text = " ".join(run("denoise", "--help").stdout.split())
    assert PROFILE_FORMS in help_text


def test_eval_metrics_help_lists_every_registered_metric() -> None:
    from mcdenoise.eval.metrics import METRICS

    help_text = " ".join(run("eval", "--help").stdout.split())
    at = help_text.index("--metrics LIST")
    for name in METRICS:
        assert name in help_text[at : at + 400], name
    assert "bias" in help_text[at : at + 400]


def test_registry_aliases_is_the_public_alias_table() -> None:
    table = registry.aliases()
    assert table["xbf"] == "cross-bilateral"
    assert all(registry.get_method(a).name == n for a, n in table.items())
    table["not-an-alias-h1"] = "nlm"  # a copy: changing it changes nothing
    assert "not-an-alias-h1" not in registry.aliases()

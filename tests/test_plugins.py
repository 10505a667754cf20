"""Plugins: methods a package declares in the entry-point group ``mcdenoise.methods`` show up
in ``mcdenoise methods`` and ``denoise`` without a change to mcdenoise; a plugin that fails to
load is an unavailable method with the reason, never a crash."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import torch
from click.testing import CliRunner
from mcdenoise_cli.main import main
from shared_inputs import EntryPoint

from mcdenoise import registry
from mcdenoise.errors import InputError
from mcdenoise.io import FeatureBuffers, load_buffers, save_buffers
from mcdenoise.method import Method

REPO = Path(__file__).resolve().parents[1]


def _double(b: FeatureBuffers, p: Any, d: torch.device) -> torch.Tensor:
    return b["color"] * 2


DOUBLE = Method("plug-double", "twice the colour", ("color",), (), {}, _double)


def test_plugins_join_the_table_and_broken_ones_say_why(plugins) -> None:
    triple = Method("plug-triple", "x3", ("color",), (), {}, lambda b, p, d: b["color"] * 3)
    plugins(
        EntryPoint("double", "plug:DOUBLE", DOUBLE),
        EntryPoint("many", "plug:methods", lambda: [triple]),
        EntryPoint("gone", "missing_pkg:M", error=ModuleNotFoundError("No module named 'x'")),
        EntryPoint("wrong", "plug:NOT_A_METHOD", 42),
        EntryPoint("exits", "plug:EXITS", error=SystemExit(2)),
        EntryPoint("nlm", "plug:MY_NLM", DOUBLE.__class__(**{**DOUBLE.__dict__, "name": "nlm"})),
    )
    names = {m.name for m in registry.methods()}
    assert {"plug-double", "plug-triple", "gone", "wrong", "plugin:nlm"} <= names
    assert registry.get_method("nlm").summary != "twice the colour"  # a built-in keeps its name
    assert registry.get_method("plug-double") is DOUBLE
    gone = registry.get_method("gone").unavailable()
    assert gone == "plugin missing_pkg:M failed to load: ModuleNotFoundError: No module named 'x'"
    assert "gave int, not mcdenoise.method.Method" in str(
        registry.get_method("wrong").unavailable()
    )
    assert "SystemExit: 2" in str(registry.get_method("exits").unavailable())
    assert "'nlm' is already taken" in str(registry.get_method("plugin:nlm").unavailable())
    fb = FeatureBuffers({"color": torch.ones(3, 2, 2)})
    from mcdenoise.denoise import denoise

    assert float(denoise(fb, "plug-triple").image.mean()) == 3.0
    with pytest.raises(InputError, match="'gone' is not available: plugin missing_pkg:M"):
        denoise(fb, "gone")
    r = CliRunner().invoke(main, ["methods"])
    assert r.exit_code == 0, r.output
    assert "plug-double" in r.output and "unavailable: plugin missing_pkg:M failed" in r.output


def test_a_plugin_list_that_fails_is_one_unavailable_entry(plugins, monkeypatch) -> None:
    plugins()

    def broken() -> list[Any]:
        raise RuntimeError("bad metadata")

    monkeypatch.setattr(registry, "_entry_points", broken)
    assert "bad metadata" in str(registry.get_method("plugins").unavailable())
    assert registry.get_method("nlm").unavailable() is None


def _documented_plugin() -> str:
    """The example package's code as docs/methods.md ("Bring your own denoiser") shows it: the
    test runs the documented example itself."""
    text = (REPO / "docs" / "methods.md").read_text(encoding="utf-8")
    start = text.index("```python\n# myplug/__init__.py\n") + len("```python\n")
    return text[start : text.index("```", start)]


def test_an_installed_package_appears_in_every_command(tmp_path: Path) -> None:
    """The documented example package as a real distribution (``.dist-info`` with
    ``entry_points.txt``) on the path, found by ``importlib.metadata`` in a fresh
    interpreter: listed, and denoising through the CLI."""
    site = tmp_path / "site"
    (site / "myplug").mkdir(parents=True)
    (site / "myplug" / "__init__.py").write_text(_documented_plugin())
    info = site / "myplug-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: myplug\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[mcdenoise.methods]\nmyplug = myplug:methods\n")
    src, out = tmp_path / "x.exr", tmp_path / "out.exr"
    color = torch.rand(3, 6, 7, generator=torch.Generator().manual_seed(0))
    save_buffers(src, FeatureBuffers({"color": color}))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(REPO)])}
    code = "from mcdenoise_cli.main import main; main()"

    def cli(*args: object) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-c", code, *map(str, args)],
            capture_output=True,
            text=True,
            env=env,
            timeout=300,
            check=False,
        )

    listed = cli("methods")
    assert listed.returncode == 0, listed.stderr
    assert "plug-box" in listed.stdout and "plug-ema" in listed.stdout
    ran = cli("denoise", src, "--method", "plug-box", "-p", "radius=1", "-o", out, "--threads", 1)
    assert ran.returncode == 0, ran.stderr
    want = torch.nn.functional.avg_pool2d(
        torch.nn.functional.pad(color[None], [1] * 4, mode="replicate"), 3, stride=1
    )[0]
    torch.testing.assert_close(load_buffers(out)["color"], want, rtol=1e-5, atol=1e-6)

"""``mcdenoise denoise --estimate-error``: the estimate in the header and the JSON record, and
the refusals (an input without halves, a temporal method), each one line, nothing written."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from click.testing import CliRunner
from mcdenoise_cli.main import main

from mcdenoise.io import FeatureBuffers, probe_exr, save_buffers


def _image(path: Path, halves: bool = True, size: int = 24) -> Path:
    g = torch.Generator().manual_seed(0)
    _y, x = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    mu = (0.3 + 0.5 * (x > size // 2)).float().expand(3, -1, -1)
    a = mu * (1 + 0.5 * torch.randn(3, size, size, generator=g)).clamp_min(0)
    b = mu * (1 + 0.5 * torch.randn(3, size, size, generator=g)).clamp_min(0)
    bufs = {"color": (a + b) / 2, "color_var": torch.full((3, size, size), 0.01)}
    if halves:
        bufs |= {"color_a": a, "color_b": b}
        bufs |= {"color_a_var": torch.full((3, size, size), 0.02)}
        bufs |= {"color_b_var": torch.full((3, size, size), 0.02)}
    save_buffers(path, FeatureBuffers(bufs, spp=8))
    return path


def run(*args: str):
    return CliRunner().invoke(main, list(args), catch_exceptions=False)


def test_estimate_in_header_and_json(tmp_path: Path) -> None:
    src = _image(tmp_path / "in.exr")
    out = tmp_path / "out.exr"
    r = run("denoise", str(src), "-m", "cross-bilateral", "--estimate-error", "--json",
            "-o", str(out), "--threads", "1")  # fmt: skip
    assert r.exit_code == 0, r.output + r.stderr
    rec = json.loads(r.stdout.strip().splitlines()[-1])
    assert rec["relmse_estimated"] >= 0 and rec["relmse_estimated_se"] > 0
    assert rec["estimate_of"] == "full"
    attrs = probe_exr(out)[0].attributes
    assert attrs["mcdenoise:relmse_estimated"] == pytest.approx(rec["relmse_estimated"])
    assert "mcdenoise:relmse_estimated_se" in attrs
    r = run("denoise", str(src), "-m", "cross-bilateral", "--estimate-error",
            "-o", str(tmp_path / "o2.exr"), "--threads", "1")  # fmt: skip
    assert "(estimated from the halves)" in r.stdout


def test_without_halves_or_with_a_temporal_method_it_is_refused(tmp_path: Path) -> None:
    src = _image(tmp_path / "plain.exr", halves=False)
    out = tmp_path / "out.exr"
    r = CliRunner().invoke(
        main, ["denoise", str(src), "-m", "cross-bilateral", "--estimate-error", "-o", str(out)]
    )
    err = r.stderr.strip()
    assert r.exit_code != 0 and len(err.splitlines()) == 1, err
    assert "no half buffers (color_a, color_b)" in err and not out.exists()
    r = CliRunner().invoke(
        main,
        ["denoise", str(tmp_path), "-m", "svgf", "--estimate-error", "-o", str(tmp_path / "o")],
    )
    assert r.exit_code != 0 and "--estimate-error judges still images" in r.output + r.stderr

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
    assert rec["estimate_normaliser"].startswith("own output")
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


def test_reference_free_report_of_several_methods(tmp_path: Path) -> None:
    from mcdenoise.eval.estimate import format_estimates, write_estimate_report
    from mcdenoise.eval.estimate_files import estimate_files

    src = _image(tmp_path / "in.exr")
    outs = tmp_path / "outs"
    for m in ("cross-bilateral", "nlm"):
        r = run("denoise", str(src), "-m", m, "--estimate-error", "-o", str(outs),
                "--threads", "1")  # fmt: skip
        assert r.exit_code == 0, r.output + r.stderr
    (tmp_path / "plain").mkdir()
    r = run("denoise", str(src), "-m", "cross-bilateral", "-o", str(tmp_path / "plain" / "x.exr"))
    assert r.exit_code == 0, r.output + r.stderr
    rows = estimate_files([outs, tmp_path / "plain" / "x.exr"])
    by = {(r["method"], r["file"].endswith("x.exr")): r for r in rows}
    assert {m for m, _ in by} == {"noisy", "cross-bilateral", "nlm"}
    assert all(r["estimated"] for r in rows)
    assert by[("nlm", False)]["relmse_estimated"] >= 0
    # without a way to run the methods again, each keeps its header's own-normalised value
    from mcdenoise.eval.estimate import OWN

    assert by[("nlm", False)]["normaliser"] == OWN and by[("nlm", False)]["note"] == ""
    assert by[("noisy", False)]["relmse_estimated"] > by[("nlm", False)]["relmse_estimated"]
    assert "--estimate-error" in by[("cross-bilateral", True)]["note"]
    paths = write_estimate_report(rows, tmp_path / "report")
    assert json.loads(paths["json"].read_text())["estimated"] is True
    page = paths["html"].read_text()
    assert "not measured" in page
    value = by[("nlm", False)]["relmse_estimated"]
    assert f"<td>{value:.4g}</td>" in page and repr(value) not in page  # readable, not 17 digits
    assert paths["csv"].read_text().splitlines()[0].endswith("estimated")
    assert format_estimates(rows).startswith("relMSE ESTIMATED without a reference")

"""``mcdenoise eval OUTPUTS`` without ``--ref``: the estimates ``denoise --estimate-error``
recorded, printed and written as a report marked estimated; outputs without any estimate are
refused with the missing option named, and nothing is written."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from click.testing import CliRunner
from mcdenoise_cli.main import main
from shared_inputs import noisy_with_halves

from mcdenoise.io import probe_exr


def run(*args: str):
    return CliRunner().invoke(main, list(args))


def test_eval_without_ref_reports_the_estimates(tmp_path: Path) -> None:
    from mcdenoise.eval.estimate import OWN

    src = noisy_with_halves(tmp_path / "in.exr")
    outs = tmp_path / "outs"
    outs.mkdir()
    for m in ("cross-bilateral", "nlm"):
        r = run("denoise", str(src), "-m", m, "--estimate-error", "-o", str(outs / f"{m}.exr"),
                "--threads", "1")  # fmt: skip
        assert r.exit_code == 0, r.output
    r = run("eval", str(outs), "-o", str(tmp_path / "rep"))
    assert r.exit_code == 0, r.output
    assert "ESTIMATED without a reference" in r.stdout
    rows = json.loads((tmp_path / "rep" / "estimate.json").read_text(encoding="utf-8"))
    rows = rows["rows"] if isinstance(rows, dict) else rows
    methods = {row["method"]: row for row in rows}
    assert {"cross-bilateral", "nlm", "noisy"} <= set(methods)
    for m in ("cross-bilateral", "nlm"):
        assert methods[m]["relmse_estimated"] > 0 and methods[m]["estimated"] is True
        # two outputs of one input: both normalised by their median (their mean), the
        # method run again on the halves; the header's own-normalised value in the note
        assert methods[m]["normaliser"].startswith("median of 2 outputs"), methods[m]
        assert methods[m]["note"].startswith("header value "), methods[m]
        assert methods[m]["note"].endswith(f"({OWN})")
    assert methods["noisy"]["normaliser"] == methods["nlm"]["normaliser"]
    assert "normalised by" in r.stdout and "median of 2 outputs" in r.stdout
    assert "normaliser" in (tmp_path / "rep" / "estimate.html").read_text(encoding="utf-8")
    # the noisy input's error is estimated above both denoisers'
    assert methods["noisy"]["relmse_estimated"] > methods["nlm"]["relmse_estimated"]
    # the shared value is the estimate with the mean of both outputs as normaliser
    from mcdenoise.denoise import denoise
    from mcdenoise.eval.estimate import estimate_from_outputs, matched_normaliser, split_halves
    from mcdenoise.io import load_buffers

    fb = load_buffers(src)
    mean = sum(load_buffers(outs / f"{m}.exr")["color"] for m in ("cross-bilateral", "nlm")) / 2
    pseudo = matched_normaliser(mean, fb["color"])
    ha, hb = split_halves(fb)
    da, db = (denoise(h, "nlm", device="cpu").image for h in (ha, hb))
    want = estimate_from_outputs(da, db, fb, normaliser=pseudo).relmse
    assert methods["nlm"]["relmse_estimated"] == pytest.approx(want, rel=1e-4)


def test_one_output_keeps_its_own_normaliser(tmp_path: Path) -> None:
    from mcdenoise.eval.estimate import OWN

    src = noisy_with_halves(tmp_path / "in.exr")
    out = tmp_path / "xbf.exr"
    r = run("denoise", str(src), "-m", "cross-bilateral", "--estimate-error", "-o", str(out),
            "--threads", "1")  # fmt: skip
    assert r.exit_code == 0, r.output
    r = run("eval", str(out), "-o", str(tmp_path / "rep"))
    assert r.exit_code == 0, r.output
    rows = json.loads((tmp_path / "rep" / "estimate.json").read_text(encoding="utf-8"))["rows"]
    row = next(x for x in rows if x["method"] == "cross-bilateral")
    assert row["normaliser"] == OWN and row["note"] == ""
    assert OWN in r.stdout


def test_eval_without_ref_and_without_estimates_is_refused(tmp_path: Path) -> None:
    src = noisy_with_halves(tmp_path / "in.exr")
    out = tmp_path / "plain.exr"
    assert run("denoise", str(src), "-m", "cross-bilateral", "-o", str(out)).exit_code == 0
    r = run("eval", str(out), "-o", str(tmp_path / "rep"))
    assert r.exit_code == 2 and "Missing option '--ref'" in r.stderr
    assert "--estimate-error" in r.stderr
    assert not (tmp_path / "rep").exists()


def test_a_method_that_needs_halves_is_written_with_no_estimate(tmp_path: Path) -> None:
    """nfor runs on the halves itself: on one half alone it has none, so --estimate-error
    writes its output and records why there is no estimate (issue 36), and eval without a
    reference says so in its row."""
    src = noisy_with_halves(tmp_path / "in.exr")
    out = tmp_path / "nfor.exr"
    r = run("denoise", str(src), "-m", "nfor", "--estimate-error", "-o", str(out))
    assert r.exit_code == 0, r.stderr
    assert "no estimate: nfor uses both halves itself" in r.stdout
    attrs = probe_exr(out)[0].attributes
    assert "mcdenoise:relmse_estimated" not in attrs
    assert attrs["mcdenoise:estimate_note"].startswith("no estimate: nfor uses both halves")
    other = tmp_path / "xbf.exr"
    r = run("denoise", str(src), "-m", "cross-bilateral", "--estimate-error", "-o", str(other))
    assert r.exit_code == 0, r.stderr
    r = run("eval", str(out), str(other), "-o", str(tmp_path / "rep"))
    assert r.exit_code == 0, r.stderr
    rows = json.loads((tmp_path / "rep" / "estimate.json").read_text())["rows"]
    nfor = next(x for x in rows if x["method"] == "nfor")
    assert nfor["relmse_estimated"] is None and "uses both halves" in nfor["note"]


def test_shared_noisy_guides_are_estimated_with_a_stated_warning(tmp_path: Path) -> None:
    """A file with colour halves but one noisy albedo for both (as renders before issue 36):
    the estimate is written with the warning in the header, the summary line, the JSON and
    the report, and with the smoothed-guide check; halved guides carry no warning."""
    from mcdenoise.io import FeatureBuffers, load_buffers, save_buffers

    src = noisy_with_halves(tmp_path / "in.exr")
    fb = load_buffers(src)
    g = torch.Generator().manual_seed(4)
    albedo_a = 0.2 + 0.6 * torch.rand(3, 24, 24, generator=g)
    albedo_b = 0.2 + 0.6 * torch.rand(3, 24, 24, generator=g)
    shared = dict(fb.buffers) | {
        "albedo": (albedo_a + albedo_b) / 2,
        "albedo_var": (albedo_a - albedo_b).square() / 4,
    }
    save_buffers(tmp_path / "shared.exr", FeatureBuffers(shared, spp=8))
    save_buffers(
        tmp_path / "halved.exr",
        FeatureBuffers(shared | {"albedo_a": albedo_a, "albedo_b": albedo_b}, spp=8),
    )
    outs = tmp_path / "outs"
    outs.mkdir()
    for name in ("shared", "halved"):
        for m in ("cross-bilateral", "nlm"):
            out = outs / f"{name}_{m}.exr"
            r = run("denoise", str(tmp_path / f"{name}.exr"), "-m", m, "--estimate-error",
                    "-o", str(out), "--threads", "1")  # fmt: skip
            assert r.exit_code == 0, r.output
            attrs = probe_exr(out)[0].attributes
            warned = "guides shared by both halves (albedo" in r.stdout
            assert warned == (name == "shared"), (name, m, r.stdout)
            assert ("mcdenoise:estimate_warning" in attrs) == warned
            assert ("mcdenoise:relmse_estimated_smoothed_guides" in attrs) == warned
    r = run("eval", *(str(p) for p in sorted(outs.glob("shared_*"))), "-o", str(tmp_path / "rep"))
    assert r.exit_code == 0, r.output
    rows = json.loads((tmp_path / "rep" / "estimate.json").read_text())["rows"]
    by = {row["method"]: row for row in rows}
    for m in ("cross-bilateral", "nlm"):  # both read the albedo (nlm as its joint guide)
        assert by[m]["warning"].startswith("guides shared by both halves (albedo"), by[m]
    assert by["noisy"]["warning"] == ""
    assert "WARNING guides shared" in r.stdout
    assert "guides shared by both halves" in (tmp_path / "rep" / "estimate.html").read_text()


def test_odd_estimate_headers_are_data_not_errors(tmp_path: Path) -> None:
    """An output whose header holds a string where a number belongs and an escape sequence in
    its warning (a file may come from anyone): one row, the string read as no value, the
    upper bound shown as ``< x``, the escape printed as text; exit 0."""
    from mcdenoise.io import FeatureBuffers, save_buffers

    attrs = {
        "mcdenoise:method": "cross-bilateral",
        "mcdenoise:relmse_estimated": "0.1; rm -rf /",
        "mcdenoise:relmse_estimated_upper": 0.25,
        "mcdenoise:relmse_estimated_se": "x",
        "mcdenoise:estimate_warning": "guides shared \x1b[31mred",
    }
    out = tmp_path / "odd.exr"
    save_buffers(out, FeatureBuffers({"color": torch.rand(3, 8, 8)}), attributes=attrs)
    r = run("eval", str(out), "-o", str(tmp_path / "rep"))
    assert r.exit_code == 0, r.output
    assert "< 0.25" in r.stdout and "\x1b" not in r.stdout and "\\x1b[31mred" in r.stdout
    row = json.loads((tmp_path / "rep" / "estimate.json").read_text())["rows"][0]
    assert row["relmse_estimated"] is None and row["relmse_estimated_se"] is None

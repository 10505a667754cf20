"""External command methods (``--method 'cmd:...'``): a real program (``tests/data/
external_denoiser.py``, which reads and writes with OpenImageIO only) run end to end through
the CLI; the files it is given; failures, timeouts and bad templates as one line."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from mcdenoise_cli.main import main

from mcdenoise import registry
from mcdenoise.denoise import denoise
from mcdenoise.errors import InputError
from mcdenoise.io import FeatureBuffers, load_buffers, save_buffers
from mcdenoise.io.exr import read_exr
from mcdenoise.methods.external import command_method, parse_template, read_pfm, write_pfm
from mcdenoise.programs import command_env
from mcdenoise.registry import parse_methods

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "tests" / "data" / "external_denoiser.py"
PY = sys.executable


def _cmd(args: str) -> str:
    return f"cmd:{PY} {SCRIPT} {args}"


def _frame(h: int = 8, w: int = 10) -> FeatureBuffers:
    g = torch.Generator().manual_seed(1)
    return FeatureBuffers(
        {
            "color": torch.rand(3, h, w, generator=g) * 4,
            "albedo": torch.rand(3, h, w, generator=g),
            "normal": torch.rand(3, h, w, generator=g) * 2 - 1,
            "depth": torch.rand(1, h, w, generator=g),
        },
        spp=4,
    )


def _box(x: np.ndarray) -> np.ndarray:  # (3, H, W), edges repeated
    h, w = x.shape[1:]
    p = np.pad(x, ((0, 0), (1, 1), (1, 1)), mode="edge")
    return sum(p[:, dy : dy + h, dx : dx + w] for dy in range(3) for dx in range(3)) / 9.0


def _cli(*args: object):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_a_command_denoises_through_the_cli_and_is_recorded(tmp_path: Path) -> None:
    src, out = tmp_path / "x.exr", tmp_path / "out.exr"
    fb = _frame()
    save_buffers(src, fb)
    spec = _cmd("blur {input} {output}")
    r = _cli("denoise", src, "--method", spec, "-o", out)
    assert r.exit_code == 0, r.output
    got = load_buffers(out)["color"].numpy()
    np.testing.assert_allclose(got, _box(fb["color"].numpy()), rtol=1e-5, atol=1e-6)
    attrs = read_exr(out).part.attributes
    assert str(attrs["mcdenoise:method"]).startswith("cmd-external_denoiser-")
    params = json.loads(str(attrs["mcdenoise:params"]))
    assert params["command"] == spec.removeprefix("cmd:")
    assert params["version"] == "external_denoiser 1.0"  # SCRIPT --version
    assert float(attrs["mcdenoise:seconds"]) > 0
    # the method is found again by its name (what an experiment records)
    assert (
        registry.get_method(str(attrs["mcdenoise:method"])).defaults["command"] == params["command"]
    )


def test_the_input_file_is_the_canonical_layout(tmp_path: Path) -> None:
    with pytest.raises(InputError) as e:
        denoise(_frame(), parse_methods(_cmd("channels {input} {output}"))[0])
    msg = str(e.value)
    assert "exited with status 4" in msg and "\n" not in msg
    names = set(msg.split("channels: ")[1].split(",")) - {""}
    assert {"R", "G", "B", "albedo.R", "normal.X", "normal.Y", "normal.Z", "depth.Z"} <= {
        n.strip() for n in names
    }


@pytest.mark.parametrize(
    ("template", "buffer"),
    [
        ("copy {albedo} {output}", "albedo"),  # default .pfm
        ("copy {normal:exr} {output:pfm} --unused {color}", "normal"),
        ("copy {color:pfm} {output}", "color"),
    ],
)
def test_oidn_style_files_hold_one_feature_each(template: str, buffer: str) -> None:
    fb = _frame()
    m = command_method(_cmd(template).removeprefix("cmd:"))
    assert buffer == "color" or buffer in m.requires
    got = denoise(fb, m).image.numpy()
    want = fb[buffer].numpy()
    if buffer == "normal":  # the output is clamped at 0 like every method's
        want = np.maximum(want, 0)
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-7)


def test_a_failing_command_is_one_line_with_its_stderr_and_writes_nothing(
    tmp_path: Path,
) -> None:
    src, out = tmp_path / "x.exr", tmp_path / "out.exr"
    save_buffers(src, _frame())
    r = _cli("denoise", src, "--method", _cmd("fail {input} {output}"), "-o", out)
    assert r.exit_code == 1
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("mcdenoise: error:"), r.output
    assert "exited with status 3" in lines[0]
    assert "loading model weights.pt | error: the tensor has the wrong shape" in lines[0]
    assert "Traceback" not in r.output and not out.exists()


@pytest.mark.parametrize(
    ("args", "what"),
    [
        ("nothing {input} {output}", "wrote no output"),
        ("half {input} {output}", "wrote a 5x8 output for a 10x8 input"),
        ("garbage {output}", "output is unreadable"),
        ("garbage {output:pfm}", "output is unreadable: .*not a PFM file"),
    ],
)
def test_a_bad_output_is_refused(args: str, what: str) -> None:
    with pytest.raises(InputError, match=what):
        denoise(_frame(), command_method(_cmd(args).removeprefix("cmd:")))


def test_the_timeout_ends_the_command() -> None:
    m = command_method(_cmd("sleep 60 {output}").removeprefix("cmd:"))
    t0 = time.perf_counter()
    with pytest.raises(InputError, match=r"ran past its timeout of 0.5 s"):
        denoise(_frame(), m, params={"timeout": "0.5"})
    assert time.perf_counter() - t0 < 20


@pytest.mark.parametrize(
    ("spec", "why"),
    [
        ("cmd:den {inptu} {output}", r"unknown placeholder \{inptu\}"),
        ("cmd:den {input}", r"no \{output\}"),
        ("cmd:den {color:png} {output}", "can be pfm or exr"),
        ("cmd:den 'a {output}", "No closing quotation"),
        ("cmd:", "needs a command"),
        ("cmd:no_such_program_xyz {input} {output}", "not found"),
    ],
)
def test_bad_templates_are_one_line(tmp_path: Path, spec: str, why: str) -> None:
    src = tmp_path / "x.exr"
    save_buffers(src, _frame())
    r = _cli("denoise", src, "--method", spec)
    assert r.exit_code != 0
    line = r.output.strip()
    assert "\n" not in line and "Traceback" not in line, r.output
    assert pytest.importorskip("re").search(why, line), line


def test_commas_stay_in_the_command_and_relative_paths_work(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.chdir(REPO)
    rel = SCRIPT.relative_to(REPO)
    chosen = parse_methods(f"nlm,cmd:{PY} {rel} blur {{input}} {{output}} --x 1,2")
    assert chosen[0].name == "nlm" and len(chosen) == 2
    assert chosen[1].defaults["command"].endswith("--x 1,2")
    fb = _frame()
    got = denoise(fb, chosen[1]).image.numpy()  # runs in a temporary folder
    np.testing.assert_allclose(got, _box(fb["color"].numpy()), rtol=1e-5, atol=1e-6)


def test_cmd_methods_are_not_in_the_table() -> None:
    m = registry.get_method(_cmd("blur {input} {output}"))
    assert m.name not in {x.name for x in registry.methods()}


def test_pfm_round_trip(tmp_path: Path) -> None:
    img = np.random.default_rng(0).random((3, 4, 5), dtype=np.float32)
    write_pfm(tmp_path / "a.pfm", img)
    np.testing.assert_array_equal(read_pfm(tmp_path / "a.pfm"), img)
    grey = img[0][::-1].astype(">f4")  # big-endian grey PFM, rows bottom to top
    (tmp_path / "g.pfm").write_bytes(b"Pf\n5 4\n1.0\n" + grey.tobytes())
    np.testing.assert_array_equal(read_pfm(tmp_path / "g.pfm"), np.stack([img[0]] * 3))
    assert parse_template("x {{a}} {output}").fill({"output": "o.exr"}) == ["x", "{a}", "o.exr"]


def test_a_named_command_is_found_by_its_name(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(registry, "_COMMANDS", dict(registry._COMMANDS))
    text = _cmd("blur {input} {output}").removeprefix("cmd:")
    m = registry.add_command(text, name="mine-blur")
    assert registry.get_method("mine-blur") is m and m.defaults["command"] == text
    assert registry.get_method("cmd:" + text).name.startswith("cmd-external_denoiser-")
    assert registry.add_command(text, name="mine-blur").name == "mine-blur"  # same again: fine
    with pytest.raises(InputError, match="names two commands"):
        registry.add_command(text + " --x", name="mine-blur")
    with pytest.raises(InputError, match="taken by a method"):
        registry.add_command(text, name="nlm")


def test_oidn_through_a_command_equals_the_builtin_oidn() -> None:
    pytest.importorskip("pyoidn")
    fb = _frame(16, 20)
    m = command_method(_cmd("oidn {color} {albedo} {normal} {output:pfm}").removeprefix("cmd:"))
    got = denoise(fb, m).image
    want = denoise(fb, "oidn").image
    torch.testing.assert_close(got, want, rtol=1e-4, atol=1e-5)


def test_an_experiment_judges_a_command(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``mcdenoise eval --experiment`` with ``cmd:`` methods in its list: the working one is
    measured, the failing one is a failed unit whose error quotes the command's stderr."""
    import csv

    monkeypatch.syspath_prepend(str(REPO / "tests" / "experiments"))
    from synthetic_data import make_render_folder

    make_render_folder(tmp_path / "data", scenes=("alpha",), size=(12, 16), spp=(1,))
    blur, fail = _cmd("blur {input} {output}"), _cmd("fail {input} {output}")
    spec = tmp_path / "exp.toml"
    spec.write_text(
        f"methods = [{json.dumps(blur)}, {json.dumps(fail)}]\nmetrics = ['relmse']\n"
        "repetitions = 1\nwarmup = 0\nthreads = 1\n[scenes]\nfolder = 'data'\n",
        encoding="utf-8",
    )
    r = _cli("eval", "--experiment", spec, "-o", tmp_path / "rep", "--allow-commands")
    rows = list(csv.DictReader((tmp_path / "rep" / "results.csv").open(encoding="utf-8")))
    by = {row["base_method"][:22]: row for row in rows if row["method"] != "noisy"}
    assert set(by) == {"cmd-external_denoiser-"}, (r.output, rows)
    done = [row for row in rows if row["method"] == blur]
    failed = [row for row in rows if row["method"] == fail]
    assert len(done) == 1 and done[0]["failed"] == "false" and float(done[0]["relmse"]) > 0
    assert len(failed) == 1 and failed[0]["failed"] == "true"
    assert "the tensor has the wrong shape" in failed[0]["error"]


def test_the_command_learns_the_thread_count(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(torch, "get_num_threads", lambda: 3)
    env = command_env({"PATH": "/bin"})
    assert env["MCDENOISE_THREADS"] == "3" and env["OMP_NUM_THREADS"] == "3"
    assert command_env({"OMP_NUM_THREADS": "1"})["OMP_NUM_THREADS"] == "1"  # the user's wins

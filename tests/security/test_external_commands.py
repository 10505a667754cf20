"""Files, specs and packages from others must not run programs (issue 33, items 1, 2, 6, 7, 9).

Each test is a case that ran a program, or left one running, before the fix:

* an output's header naming a command made ``mcdenoise eval`` (no ``--ref``) run it;
* building a command method ran ``PROGRAM --version`` at once (a name looked up, a spec read);
* an experiment spec ran its ``[[external]]`` / ``cmd:`` programs with no say of the user;
* an installed plugin could make itself the default by its priority;
* ``kill -9`` of mcdenoise left the command running, and its temporary folder behind;
* a ``cmd:`` argument that happened to be a file name in the current folder became a path.

The programs here write a marker file whenever they run at all, ``--version`` included, so
"nothing ran" is a file that does not exist.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import Any

import pytest
import torch
from click.testing import CliRunner
from mcdenoise_cli.main import main
from shared_inputs import EntryPoint, noisy_with_halves

from mcdenoise import registry
from mcdenoise.errors import InputError
from mcdenoise.experiments.spec import load_experiment
from mcdenoise.experiments.spec_fields import ExperimentError
from mcdenoise.io import FeatureBuffers, load_buffers, save_buffers
from mcdenoise.io.exr import read_exr
from mcdenoise.io.exr_write import write_exr
from mcdenoise.method import Method
from mcdenoise.methods.external import _absolute_args, command_method
from mcdenoise.programs import FOLDER_PREFIX, STALE_SECONDS, _setpriv, sweep_stale_folders

REPO = Path(__file__).resolve().parents[2]
DENOISER = REPO / "tests" / "data" / "external_denoiser.py"
PY = sys.executable

#: A program that leaves a marker beside itself (``MARKER``, one line per run: its
#: arguments) whenever it runs, answers ``--version``, and otherwise copies its first
#: argument to its second (PFM files: no image library needed).
MARKER_PROGRAM = """\
import shutil, sys
from pathlib import Path
with open(Path(__file__).with_name("MARKER"), "a") as f:
    f.write(" ".join(sys.argv[1:]) + "\\n")
if sys.argv[1:] == ["--version"]:
    print("marker 2.0")
else:
    shutil.copyfile(sys.argv[1], sys.argv[2])
"""


@pytest.fixture(autouse=True)
def _own_commands(monkeypatch: pytest.MonkeyPatch) -> None:
    """Commands built by a test are forgotten afterwards (names are process-wide)."""
    monkeypatch.setattr(registry, "_COMMANDS", dict(registry._COMMANDS))


def _marker_program(tmp_path: Path) -> tuple[Path, Path]:
    """``(program, marker)``: the marker program and the file it writes when run."""
    prog = tmp_path / "marker_prog.py"
    prog.write_text(MARKER_PROGRAM, encoding="utf-8")
    return prog, tmp_path / "MARKER"


def _marker_command(prog: Path) -> str:
    """A command template running the marker program (its version probe is
    ``python SCRIPT --version``)."""
    return f"{PY} {prog} {{color}} {{output:pfm}}"


def _rewrite_header(path: Path, method: str, params: dict[str, Any]) -> None:
    """What someone who sends an output folder can do: name any method in its header."""
    img = read_exr(path)
    attrs = {k: v for k, v in img.part.attributes.items() if k.startswith("mcdenoise:")}
    attrs["mcdenoise:method"] = method
    attrs["mcdenoise:params"] = json.dumps(params)
    write_exr(path, dict(img.pixels), attributes=attrs)


# --- 1. a file's header never runs a program --------------------------------------------------


@pytest.mark.parametrize("kind", ["cmd:", "generated name", "built before"])
def test_an_output_header_naming_a_command_runs_nothing(tmp_path: Path, kind: str) -> None:
    """The issue's reproduction: ``denoise --method nlm,cross-bilateral --estimate-error``,
    the nlm output's header rewritten to a command, then ``mcdenoise eval out/`` (no
    ``--ref``, which re-runs each header's method on the halves). Nothing runs; one line
    names the file and why; the other output is still re-estimated."""
    prog, marker = _marker_program(tmp_path)
    src = noisy_with_halves(tmp_path / "in.exr")
    out = tmp_path / "out"
    args = ["denoise", str(src), "-m", "nlm,cross-bilateral", "--estimate-error", "-o", str(out)]
    r = CliRunner().invoke(main, [*args, "--threads", "1"])
    assert r.exit_code == 0, r.output
    template = _marker_command(prog)
    if kind == "cmd:":
        name = "cmd:" + template
    elif kind == "generated name":
        name = "cmd-marker_prog-0a1b2c"  # the form of a command's name, never built here
    else:  # a command this process built (a library caller's), named by the file
        name = registry.add_command(template).name
    nlm_out = out / "in_nlm.exr"
    _rewrite_header(nlm_out, name, {} if kind == "cmd:" else {"command": template})
    r = CliRunner().invoke(main, ["eval", str(out), "-o", str(tmp_path / "rep")])
    assert r.exit_code == 0, r.output
    assert not marker.exists(), marker.read_text()
    refused = [ln for ln in r.stderr.splitlines() if "its header names the external command" in ln]
    assert len(refused) == 1 and str(nlm_out) in refused[0], r.stderr
    assert "not run" in refused[0] and "Traceback" not in r.output
    rows = json.loads((tmp_path / "rep" / "estimate.json").read_text(encoding="utf-8"))["rows"]
    by = {row["method"]: row for row in rows}
    assert by[name.strip()]["note"].startswith("own normaliser: ")  # its header value kept
    assert by["cross-bilateral"]["normaliser"].startswith("median of 2 outputs")


def test_a_header_method_is_only_ever_an_installed_one() -> None:
    """The lookup a header goes through: built-ins and aliases; a command, or a method not
    installed here (a plugin of the sender's machine), is one line naming the file."""
    assert registry.header_method("xbf", "a.exr").name == "cross-bilateral"
    for name, why in [
        ("cmd:touch x {output}", "names the external command"),
        ("cmd-touch-abcdef", "names the external command"),
        ("plug-not-here", "names method 'plug-not-here', which is not installed here"),
        ("xbf,cmd:touch x {output}", "not installed here"),
    ]:
        with pytest.raises(InputError) as err:
            registry.header_method(name, "folder/a.exr")
        assert str(err.value).startswith("folder/a.exr: its header ") and why in str(err.value)
        assert "\n" not in str(err.value)


def _set_header(path: Path, **strings: str) -> None:
    """Header strings set verbatim (not JSON-encoded): what a hand-edited file can hold."""
    img = read_exr(path)
    attrs = {k: v for k, v in img.part.attributes.items() if k.startswith("mcdenoise:")}
    attrs.update({"mcdenoise:" + k: v for k, v in strings.items()})
    write_exr(path, dict(img.pixels), attributes=attrs)


@pytest.mark.parametrize(
    ("params", "why"),
    [
        ("[1, 2]", "not a JSON object (a list)"),
        ('"text"', "not a JSON object (a str)"),
        ("[" * 100_000, "nested too deeply"),
        ('{"features": 5}', "not iterable"),
        # a window of 2e26 pixels: ran for hours before the filters bounded their windows
        ('{"search_radius": 99999999999999999999999999}', "search_radius must be at most 64"),
        ('{"patch_radius": 100}', "patch_radius must be at most 64"),
    ],
)
def test_an_output_header_with_odd_params_is_a_note_not_an_internal_error(
    tmp_path: Path, params: str, why: str
) -> None:
    """``mcdenoise:params`` that is JSON but not an object, nested past the recursion limit,
    or of the wrong type for a parameter: the row keeps its header value with a note saying
    why it did not run again (was: internal error, exit 1, no report)."""
    src = noisy_with_halves(tmp_path / "in.exr")
    out = tmp_path / "out"
    args = ["denoise", str(src), "-m", "nlm,cross-bilateral", "--estimate-error", "-o", str(out)]
    assert CliRunner().invoke(main, [*args, "--threads", "1"]).exit_code == 0
    _set_header(out / "in_nlm.exr", params=params)
    r = CliRunner().invoke(main, ["eval", str(out), "-o", str(tmp_path / "rep")])
    assert r.exit_code == 0, r.output
    assert "internal error" not in r.output and "Traceback" not in r.output
    rows = json.loads((tmp_path / "rep" / "estimate.json").read_text(encoding="utf-8"))["rows"]
    note = {row["method"]: row["note"] for row in rows}["nlm"]
    assert note.startswith("own normaliser: nlm did not run again: ") and why in note


def test_a_header_method_with_control_characters_keeps_the_table_one_line_a_row(
    tmp_path: Path,
) -> None:
    """A method name with a newline or a terminal escape (a hand-edited header) is shown
    escaped in the tables of ``eval`` with and without ``--ref``: one line per row."""
    src = noisy_with_halves(tmp_path / "in.exr")
    out = tmp_path / "out"
    args = ["denoise", str(src), "-m", "nlm,cross-bilateral", "--estimate-error", "-o", str(out)]
    assert CliRunner().invoke(main, [*args, "--threads", "1"]).exit_code == 0
    name = "nlm\ncmd:touch MARKER {output}\x1b[2J"
    _set_header(out / "in_nlm.exr", method=name)
    r = CliRunner().invoke(main, ["eval", str(out), "-o", str(tmp_path / "rep")])
    assert r.exit_code == 0, r.output
    row = [ln for ln in r.stdout.splitlines() if "cmd:touch" in ln]
    assert len(row) == 1 and row[0].split()[2] == "nlm\\ncmd:touch", r.stdout
    r = CliRunner().invoke(
        main, ["eval", "--ref", str(src), str(out / "in_nlm.exr"), "-o", str(tmp_path / "r2")]
    )
    assert r.exit_code == 0, r.output
    row = [ln for ln in r.stdout.splitlines() if "cmd:touch" in ln]
    assert len(row) == 1 and "\\x1b[2J" in row[0] and "\x1b" not in row[0], r.stdout


# --- 1/2. no program runs before the user asks for a denoise that needs it -------------------


def test_building_a_command_method_runs_no_program(tmp_path: Path) -> None:
    """``--version`` is asked when the method's parameters are first resolved for a denoise,
    not when it is built or found by name; the output records it as before."""
    prog, marker = _marker_program(tmp_path)
    template = _marker_command(prog)
    m = registry.get_method("cmd:" + template)
    assert registry.get_method(m.name) is m
    command_method(template)
    registry.add_command(template, name="mine")
    assert "version" in m.defaults and m.defaults["command"] == template
    assert not marker.exists()  # built, found, listed: nothing ran
    src = tmp_path / "x.exr"
    save_buffers(src, FeatureBuffers({"color": torch.rand(3, 4, 5)}))
    args = ["denoise", str(src), "-m", "cmd:" + template, "-o", str(tmp_path / "o.exr")]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    runs = marker.read_text().splitlines()
    assert runs[0] == "--version" and len(runs) == 2  # asked once, then the denoise
    params = json.loads(str(read_exr(tmp_path / "o.exr").part.attributes["mcdenoise:params"]))
    assert params["version"] == "marker 2.0" and params["command"] == template
    with pytest.raises(InputError, match="fixed"):  # provenance cannot be set by --param
        from mcdenoise.denoise import denoise

        denoise(load_buffers(src), m, params={"version": "forged"})


# --- 2. an experiment spec that runs programs needs --allow-commands --------------------------


def _spec_with_commands(tmp_path: Path) -> tuple[Path, Path, Path]:
    """``(spec, marker, program)``: a spec whose [[external]] is a script beside it and whose
    methods also name a ``cmd:`` command; both programs leave the marker."""
    prog, marker = _marker_program(tmp_path / "from-someone")
    spec = tmp_path / "from-someone" / "exp.toml"
    spec.write_text(
        textwrap.dedent(
            f"""\
            methods = ["mine", {json.dumps("cmd:" + _marker_command(prog))}]
            [[external]]
            name = "mine"
            command = "{Path(PY).as_posix()} marker_prog.py {{color}} {{output:pfm}}"
            [params.mine]
            timeout = 30
            [[sweep]]
            method = "mine"
            param = "timeout"
            values = [5, 9]
            [scenes]
            random = 1
            """
        ),
        encoding="utf-8",
    )
    return spec, marker, prog


@pytest.mark.parametrize("extra", [[], ["--merge"], ["--shard", "1/2"]])
def test_a_spec_that_runs_programs_is_refused_without_allow_commands(
    tmp_path: Path, extra: list[str]
) -> None:
    (tmp_path / "from-someone").mkdir()
    spec, marker, prog = _spec_with_commands(tmp_path)
    out = tmp_path / "rep"
    r = CliRunner().invoke(main, ["eval", "--experiment", str(spec), "-o", str(out), *extra])
    assert r.exit_code != 0 and "Traceback" not in r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1, r.output
    line = lines[0]
    assert f"{spec}: the spec runs 2 external program(s)" in line
    assert "refused without --allow-commands" in line
    # each command line, as it would run: the script beside the spec made absolute
    assert f"{prog} '{{color}}'" in line and "(external[0] 'mine')" in line
    assert f"{prog} {{color}}" in line and "(methods[1])" in line
    assert not marker.exists() and not out.exists()


def test_a_spec_that_runs_programs_loads_with_allow_commands_and_still_runs_nothing(
    tmp_path: Path,
) -> None:
    (tmp_path / "from-someone").mkdir()
    spec, marker, prog = _spec_with_commands(tmp_path)
    with pytest.raises(ExperimentError, match="refused without --allow-commands"):
        load_experiment(spec)
    loaded = load_experiment(spec, allow_commands=True)
    assert [e.name for e in loaded.externals] == ["mine"] and len(loaded.methods) == 2
    assert str(prog) in loaded.externals[0].command
    assert loaded.params["mine"] == {"timeout": 30} and len(loaded.sweeps) == 1
    assert not marker.exists()  # parsed, registered, params checked: no --version probe


@pytest.mark.parametrize("value", ["5", '"x"', "true", "[5]"])
def test_a_spec_whose_external_is_not_a_list_of_tables_is_one_line(
    tmp_path: Path, value: str
) -> None:
    """``external = 5`` (not a list of tables): the command listing skips it and the parser
    names it, instead of an internal error (review of issue 33 item 2)."""
    spec = tmp_path / "exp.toml"
    spec.write_text(f"external = {value}\n[scenes]\nrandom = 1\n", encoding="utf-8")
    r = CliRunner().invoke(main, ["eval", "--experiment", str(spec), "-o", str(tmp_path / "o")])
    assert r.exit_code == 1 and "internal error" not in r.output, r.output
    assert r.stderr.strip().startswith(f"mcdenoise: error: {spec}: external")
    assert len(r.stderr.strip().splitlines()) == 1


def test_allow_commands_is_refused_without_an_experiment(tmp_path: Path) -> None:
    r = CliRunner().invoke(main, ["eval", str(tmp_path), "--allow-commands"])
    assert r.exit_code == 2 and "--allow-commands applies to --experiment" in r.output


# --- 2. a plugin is never the default ---------------------------------------------------------


def _grab(b: FeatureBuffers, p: Any, d: torch.device) -> torch.Tensor:
    return b["color"] * 0


def test_a_plugin_of_top_priority_is_not_the_default(plugins) -> None:
    """A plugin ranked above every built-in runs when named (or with ``all``), never
    unasked: ``denoise`` without ``--method`` still runs a built-in."""
    greedy = Method("plug-greedy", "takes over", ("color",), (), {}, _grab, priority=10**6)
    plugins(EntryPoint("greedy", "plug:GREEDY", greedy))
    fb = FeatureBuffers({"color": torch.ones(3, 8, 8)})
    from mcdenoise.denoise import denoise
    from mcdenoise.registry import parse_methods

    assert denoise(fb, "auto").method != "plug-greedy"
    assert parse_methods("auto")[0].name != "plug-greedy"
    assert registry.best_method().name != "plug-greedy"
    choice = registry.choose_method(fb)
    assert ("plug-greedy", "a plugin: never the default (name it with --method)") in choice.skipped
    assert registry.is_plugin("plug-greedy") and not registry.is_plugin(choice.method.name)
    assert float(denoise(fb, "plug-greedy").image.sum()) == 0.0  # named: it runs
    assert "plug-greedy" in {m.name for m in parse_methods("all")}


def test_a_plugin_cannot_take_a_builtin_name_by_registering_it(plugins) -> None:
    """A plugin that calls ``register()`` while it loads, to put its code under a built-in's
    name (and so become whatever default that built-in is), is refused: the built-in stays,
    the plugin is an unavailable entry saying why."""

    def takes_nlm() -> Method:
        return registry.register(Method("nlm", "not nlm", ("color",), (), {}, _grab, 10**6))

    plugins(EntryPoint("sly", "plug:sly", takes_nlm))
    fb = FeatureBuffers({"color": torch.ones(3, 8, 8)})
    from mcdenoise.denoise import denoise

    assert denoise(fb, "auto").method == registry.choose_method(fb).method.name
    assert float(denoise(fb, "auto").image.sum()) > 0
    assert registry.get_method("nlm").summary != "not nlm"
    assert "'nlm' is already taken" in str(registry.get_method("sly").unavailable())


# --- 6. a command dies with mcdenoise; its folder is swept ------------------------------------

#: The command: starts a program of its own (a grandchild of mcdenoise, which the parent-death
#: signal does not reach), writes both pids, sleeps.
SLEEPER = """\
import os, subprocess, sys, time
own = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
with open(sys.argv[1] + ".tmp", "w") as f:
    f.write(f"{os.getpid()} {own.pid}")
os.replace(sys.argv[1] + ".tmp", sys.argv[1])
time.sleep(120)
"""

#: The parent: mcdenoise running the sleeper as a command (what ``denoise -m cmd:...`` does);
#: ``preexec``: without ``setpriv``, so the request is made before ``exec`` instead.
PARENT = """\
import sys, torch
from mcdenoise.io import FeatureBuffers
from mcdenoise import programs
from mcdenoise.methods import external
if sys.argv[2] == "preexec":
    programs._setpriv = lambda: ()
template = external.parse_template(sys.argv[1])
external.run_command(template, FeatureBuffers({"color": torch.ones(3, 4, 4)}), timeout=300)
"""


def _running(pid: int) -> bool:
    """Whether ``pid`` is a live process (a zombie waiting for its reaper is not)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] not in ("Z", "X")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
@pytest.mark.parametrize("how", ["setpriv", "preexec"])
def test_a_command_dies_with_mcdenoise_and_its_folder_is_swept(tmp_path: Path, how: str) -> None:
    if how == "setpriv" and not _setpriv():
        pytest.skip("no setpriv --pdeathsig here (util-linux 2.33+)")
    sleeper, pid_file, temp = tmp_path / "sleeper.py", tmp_path / "child.pid", tmp_path / "tmp"
    sleeper.write_text(SLEEPER, encoding="utf-8")
    temp.mkdir()
    parent = subprocess.Popen(
        [PY, "-c", PARENT, f"{PY} {sleeper} {pid_file} {{output}}", how],
        env={**os.environ, "TMPDIR": str(temp)},
    )
    pids: list[int] = []
    try:
        deadline = time.monotonic() + 60
        while not pid_file.is_file():
            assert parent.poll() is None, "the parent ended before the command started"
            assert time.monotonic() < deadline, "the command never started"
            time.sleep(0.05)
        pids = [int(x) for x in pid_file.read_text().split()]
        child, own = pids
        assert _running(child) and _running(own)
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 5
        while _running(child) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _running(child), "the command outlived a kill -9 of mcdenoise"
        # what the command started itself: ended by the group watcher, with no later run
        deadline = time.monotonic() + 5
        while _running(own) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _running(own), "the command's own program outlived a kill -9 of mcdenoise"
        left = [p for p in temp.iterdir() if p.name.startswith(f"{FOLDER_PREFIX}{parent.pid}-")]
        assert len(left) == 1  # SIGKILL leaves the folder; the next command's sweep removes it
        assert sweep_stale_folders(temp) == left and not left[0].exists()
    finally:
        if parent.poll() is None:
            parent.kill()
        for pid in pids:
            if _running(pid):
                os.kill(pid, signal.SIGKILL)
    mine = temp / f"{FOLDER_PREFIX}{os.getpid()}-live"  # a running process's: kept
    old, new = temp / f"{FOLDER_PREFIX}oldformat", temp / f"{FOLDER_PREFIX}freshformat"
    for d in (mine, old, new):
        d.mkdir()
    past = time.time() - STALE_SECONDS - 60
    os.utime(old, (past, past))
    assert sweep_stale_folders(temp) == [old]
    assert mine.is_dir() and new.is_dir() and not old.exists()


# --- 7. a word is not a path because a file of that name is here ------------------------------


def test_only_path_like_arguments_are_made_absolute(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``den --mode blur`` in a folder that holds a file ``blur`` passed ``/that/folder/blur``
    to the program; now only the program, an interpreter's script and tokens holding a path
    separator are made absolute."""
    monkeypatch.chdir(tmp_path)
    here = Path.cwd()
    (here / "sub").mkdir()
    for name in ("blur", "den.py", "sub/w.pt"):
        (here / name).touch()
    args = _absolute_args(["den.py", "blur", "sub/w.pt", "./blur", "-x", "gone/y"], "python3")
    want = [str(here / "den.py"), "blur", str(here / "sub" / "w.pt"), str(here / "blur")]
    assert args == [*want, "-x", "gone/y"]
    assert _absolute_args(["blur", "den.py"], "/usr/bin/den") == ["blur", "den.py"]
    # end to end: the test denoiser's mode "blur" beside a file named blur
    fb = FeatureBuffers({"color": torch.rand(3, 6, 7)})
    from mcdenoise.denoise import denoise

    m = command_method(f"{PY} {DENOISER} blur {{input}} {{output}}")
    assert denoise(fb, m).image.shape == (3, 6, 7)


def test_a_spec_word_is_not_made_a_path_beside_the_spec(tmp_path: Path) -> None:
    (tmp_path / "blur").touch()
    (tmp_path / "den.py").touch()
    spec = tmp_path / "exp.toml"
    spec.write_text(
        f'methods = ["mine"]\n[[external]]\nname = "mine"\n'
        f'command = "{Path(PY).as_posix()} den.py blur {{input}} {{output}}"\n'
        "[scenes]\nrandom = 1\n",
        encoding="utf-8",
    )
    command = load_experiment(spec, allow_commands=True).externals[0].command
    assert f"{tmp_path / 'den.py'} blur " in command

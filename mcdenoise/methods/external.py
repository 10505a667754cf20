"""External command methods: any denoiser program, judged like the built-in methods.

``--method 'cmd:my_denoiser --in {input} --out {output}'`` builds a per-frame
:class:`~mcdenoise.method.Method` from a command template (:func:`command_method`). For each
frame mcdenoise writes the inputs the template names into a fresh temporary folder, runs the
command there, reads ``{output}`` back and checks its size. The placeholders:

==================  ===================================================================
``{input}``         one EXR in the canonical ``mcdenoise`` layout (``R,G,B``,
                    ``albedo.R/G/B``, ``normal.X/Y/Z``, ``depth.Z``, variances, ...: every
                    buffer the input has; :func:`mcdenoise.io.save_buffers`)
``{color}``         OIDN's one-feature-per-file convention (``oidnDenoise --hdr {color}
``{albedo}``        --alb {albedo} --nrm {normal} -o {output:pfm}``): one 3-channel image
``{normal}``        each, PFM by default (what every build of OIDN's tools reads), EXR with
                    ``{color:exr}`` (channels ``R,G,B``). Values as stored: HDR colour,
                    world-space normals in [-1, 1]; a template naming ``{albedo}`` or
                    ``{normal}`` requires that buffer.
``{output}``        where the command writes its result: an EXR whose ``R,G,B`` are read
                    (``{output:pfm}``: a colour PFM). Required.
``{{`` ``}}``       literal braces.
==================  ===================================================================

The template is split like a shell would (:func:`shlex.split`) but run without one, so a path
with spaces stays one argument and nothing is expanded. The command runs with the temporary
folder as its working directory (its scratch files go away with it); so that the template
reads as it would in a shell, the program, an interpreter's script (``python my.py``) and
every argument holding a path separator (``models/w.pt``, ``./x``) that names a file or
folder existing relative to the folder mcdenoise was started in are made absolute first
(:func:`_absolute_args`). Any other word stays as written, even where a file of that name
happens to exist (``--mode blur`` beside a file ``blur``).

The command dies with mcdenoise: on Linux the kernel kills it (``SIGKILL``) when the thread
that started it ends, a ``kill -9`` of mcdenoise included (``PR_SET_PDEATHSIG``, set by
``setpriv`` or else before ``exec``: :func:`_with_parent`). It runs in a session of its own,
so what it started is ended with it: at a timeout or Ctrl-C by mcdenoise, at a ``kill -9`` of
mcdenoise by a watcher process that waits on a pipe only mcdenoise holds
(:func:`mcdenoise.programs._group_watcher`). The temporary folders of commands whose mcdenoise process is gone
(``mcdenoise-cmd-<pid>-*``), and any older than an hour without a recorded process, are
removed before the next command runs, and a program still working in such a folder (one that
left the command's process group) is ended then (:func:`mcdenoise.programs.sweep_stale_folders`).

The command gets mcdenoise's environment plus the thread count it runs with
(``MCDENOISE_THREADS``, and ``OMP_NUM_THREADS`` unless set): :func:`command_env`.

A failure (a non-zero exit, the timeout, no output, an output without ``R,G,B`` or of
another size) is one :class:`~mcdenoise.errors.InputError` line ending with the command's
last stderr lines. The method's time (``mcdenoise:seconds``, the experiment's timings) is
the whole process: writing its inputs, starting the program, its own loading and work, and
reading its output, so it is not comparable with an in-process method's time on the same
footing (the reports say so through the method's summary). Provenance: the parameters
recorded in every output (``mcdenoise:params``) hold the command template and the first line
that ``PROGRAM --version`` (``python SCRIPT --version`` for a script run by an interpreter)
printed within 2 seconds with exit status 0 (empty when it did not answer so). That probe
runs the program too, so it is never run when the method is built (a spec parsed, a name
looked up): only when the method's parameters are first read for a denoise that needs them
(:class:`CommandParams`).
"""

from __future__ import annotations

import hashlib
import os
import re
import shlex
import shutil
import subprocess
import tempfile
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mcdenoise.errors import InputError, McdenoiseError
from mcdenoise.io import FeatureBuffers, save_buffers
from mcdenoise.io.buffers import BUFFER_NAMES
from mcdenoise.io.exr import read_exr
from mcdenoise.io.exr_write import write_exr
from mcdenoise.method import Method
from mcdenoise.programs import (
    FOLDER_PREFIX,
    VERSION_TIMEOUT,
    _group_watcher,
    _kill,
    _stop_watcher,
    _sweep_once,
    _with_parent,
    command_env,
)

#: What ``--method cmd:...`` starts with.
PREFIX = "cmd:"
#: Seconds a command may run per frame, unless ``--param timeout=...`` says otherwise.
DEFAULT_TIMEOUT = 600.0
#: Placeholder -> the formats it can be written in (the first is the default).
PLACEHOLDERS: dict[str, tuple[str, ...]] = {
    "input": ("exr",),
    "color": ("pfm", "exr"),
    "albedo": ("pfm", "exr"),
    "normal": ("pfm", "exr"),
    "output": ("exr", "pfm"),
}
#: stderr lines quoted in a failure.
STDERR_LINES = 5

_FIELD = re.compile(r"\{\{|\}\}|\{([^{}]*)\}|[{}]")
#: Interpreters whose script (the next argument) names the method.
_INTERPRETERS = re.compile(r"^(python[0-9.]*|pypy[0-9.]*|sh|bash|zsh|node|ruby|perl|Rscript)$")


@dataclass(frozen=True)
class Template:
    """A parsed command template: ``argv`` tokens with their placeholders.

    Attributes:
        text: the template as given.
        argv: the tokens after :func:`shlex.split`, placeholders still in.
        fields: placeholder -> format (``exr`` or ``pfm``) for every placeholder used.
    """

    text: str
    argv: tuple[str, ...]
    fields: Mapping[str, str]

    def fill(self, paths: Mapping[str, str]) -> list[str]:
        """``argv`` with each placeholder replaced by its path and ``{{``/``}}`` unescaped."""

        def sub(m: re.Match[str]) -> str:
            if m.group(0) in ("{{", "}}"):
                return m.group(0)[0]
            return paths[m.group(1).partition(":")[0].strip()]

        return [_FIELD.sub(sub, token) for token in self.argv]


def parse_template(text: str) -> Template:
    """Check and split a command template (see the module docstring).

    Raises:
        InputError: empty, unbalanced quotes or braces, an unknown placeholder or format, no
            ``{output}``, a placeholder as the program, or two formats for one placeholder.
    """
    where = f"command {text!r}"
    try:
        argv = shlex.split(text)
    except ValueError as err:
        raise InputError(f"{where}: {err}") from None
    if not argv:
        raise InputError("cmd: needs a command, e.g. 'cmd:my_denoiser {input} {output}'")
    fields: dict[str, str] = {}
    for i, token in enumerate(argv):
        for m in _FIELD.finditer(token):
            if m.group(0) in ("{{", "}}"):
                continue
            if m.group(1) is None:
                raise InputError(f"{where}: a lone {m.group(0)!r} (write {{{{ or }}}})")
            name, _, fmt = (s.strip() for s in m.group(1).partition(":"))
            if name not in PLACEHOLDERS:
                known = ", ".join("{" + k + "}" for k in PLACEHOLDERS)
                raise InputError(f"{where}: unknown placeholder {{{m.group(1)}}} (known: {known})")
            formats = PLACEHOLDERS[name]
            fmt = fmt.lower() or formats[0]
            if fmt not in formats:
                raise InputError(f"{where}: {{{name}}} can be {' or '.join(formats)}, not {fmt!r}")
            if fields.setdefault(name, fmt) != fmt:
                raise InputError(f"{where}: {{{name}}} is asked for as two formats")
            if i == 0:
                raise InputError(f"{where}: the program cannot be a placeholder")
    if "output" not in fields:
        raise InputError(f"{where}: no {{output}} (where the command writes its R,G,B EXR)")
    return Template(text, tuple(argv), fields)


def is_interpreter(program: str) -> bool:
    """Whether ``program`` (a name or path) is an interpreter whose next argument is the
    script that names the method (``python``, ``sh``, ``node``, ...)."""
    return bool(_INTERPRETERS.match(Path(program).name))


def _stem(argv: tuple[str, ...]) -> str:
    """The program's name, or the script's for an interpreter (``python x.py`` -> ``x``)."""
    prog = Path(argv[0]).name
    if _INTERPRETERS.match(prog) and len(argv) > 1 and not argv[1].startswith("-"):
        if "{" not in argv[1]:
            prog = Path(argv[1]).name
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "-", Path(prog).stem).strip("-.") or "command"
    return stem[:40]


def method_name(text: str) -> str:
    """The file-safe name of a template's method: ``cmd-<program>-<6 hex of the template>``
    (output files are ``<stem>_<method>.exr``, so the name cannot be the template)."""
    argv = parse_template(text).argv
    digest = hashlib.sha1(text.strip().encode("utf-8")).hexdigest()[:6]
    return f"cmd-{_stem(argv)}-{digest}"


def _program(argv0: str) -> str | None:
    """The program's absolute path: a path (relative to the current folder) or on PATH."""
    if _has_separator(argv0):
        p = Path(argv0).expanduser()
        # abspath, not resolve: a venv's python is a symlink that must stay the venv's
        return os.path.abspath(p) if p.is_file() and os.access(p, os.X_OK) else None
    return shutil.which(argv0)


def _has_separator(token: str) -> bool:
    return os.sep in token or bool(os.altsep and os.altsep in token)


def _absolute_args(argv: list[str], program: str) -> list[str]:
    """The arguments after the program (``argv[1:]`` of the template, placeholders filled)
    with the ones that name a path made absolute, since the command runs in a temporary
    folder: an interpreter's script (``python my.py``: the next argument when ``program`` is
    an interpreter) and every argument holding a path separator, when it exists relative to
    the current folder. A plain word stays as written even when a file of that name exists
    here (``blur`` in ``den --mode blur``): a path is what the template says is one."""
    out = []
    for i, token in enumerate(argv):
        script = i == 0 and is_interpreter(program)
        path_like = script or _has_separator(token)
        if path_like and token and not token.startswith("-") and not os.path.isabs(token):
            p = Path(token)
            if p.exists():
                token = os.path.abspath(p)
        out.append(token)
    return out


def _version_argv(program: str, argv: tuple[str, ...]) -> list[str]:
    """``PROGRAM --version``, or ``INTERPRETER SCRIPT --version`` for a script."""
    if _INTERPRETERS.match(Path(argv[0]).name) and len(argv) > 1:
        script = argv[1]
        if not script.startswith("-") and "{" not in script and Path(script).is_file():
            return [program, os.path.abspath(script), "--version"]
    return [program, "--version"]


@lru_cache(maxsize=64)
def program_version(argv: tuple[str, ...]) -> str:
    """The first line ``argv`` (``PROGRAM --version``) prints within
    :data:`VERSION_TIMEOUT` seconds and exits 0 on, or ``""``."""
    try:
        done = subprocess.run(
            list(argv),
            capture_output=True,
            text=True,
            timeout=VERSION_TIMEOUT,
            stdin=subprocess.DEVNULL,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return ""
    if done.returncode != 0:
        return ""
    lines = [s.strip() for s in (done.stdout + "\n" + done.stderr).splitlines() if s.strip()]
    return lines[0][:200] if lines else ""


def _tail(text: str, n: int = STDERR_LINES) -> str:
    lines = [s.strip() for s in text.splitlines() if s.strip()]
    return " | ".join(lines[-n:])


def write_pfm(path: str | os.PathLike[str], image: np.ndarray) -> None:
    """``(3, H, W)`` float32 as a colour PFM (``PF``, little-endian, rows bottom to top)."""
    c, h, w = image.shape
    if c != 3:
        raise InputError(f"{path}: a colour PFM needs 3 channels, got {c}")
    hwc = np.ascontiguousarray(image.transpose(1, 2, 0)[::-1], dtype="<f4")
    with open(path, "wb") as f:
        f.write(f"PF\n{w} {h}\n-1.0\n".encode("ascii"))
        f.write(hwc.tobytes())


def read_pfm(path: str | os.PathLike[str]) -> np.ndarray:
    """A PFM (``PF`` colour or ``Pf`` grey, either byte order) as ``(3, H, W)`` float32."""
    with open(path, "rb") as f:
        data = f.read()
    m = re.match(rb"(P[Ff])\s+(\d+)\s+(\d+)\s+(\S+)\s", data)
    if m is None:
        raise InputError(f"{path}: not a PFM file")
    try:
        w, h, scale = int(m.group(2)), int(m.group(3)), float(m.group(4))
    except ValueError:
        raise InputError(f"{path}: bad PFM header") from None
    c = 3 if m.group(1) == b"PF" else 1
    body = data[m.end() :]
    if len(body) < w * h * c * 4:
        raise InputError(f"{path}: PFM is truncated ({len(body)} bytes for {w}x{h}x{c})")
    arr = np.frombuffer(body[: w * h * c * 4], dtype="<f4" if scale < 0 else ">f4")
    img = arr.reshape(h, w, c)[::-1].astype(np.float32)
    if c == 1:
        img = np.repeat(img, 3, axis=2)
    return np.ascontiguousarray(img.transpose(2, 0, 1))


def _write_feature(path: Path, image: torch.Tensor, fmt: str) -> None:
    arr = image.detach().to("cpu", torch.float32).numpy()
    if fmt == "pfm":
        write_pfm(path, arr)
    else:
        write_exr(path, {"R": arr[0], "G": arr[1], "B": arr[2]})


def _read_output(path: Path, fmt: str) -> np.ndarray:
    if not path.is_file():
        raise InputError("wrote no output")
    try:
        if fmt == "pfm":
            return read_pfm(path)
        px = read_exr(path, channels=["R", "G", "B"]).pixels
        return np.stack([px["R"], px["G"], px["B"]])
    except McdenoiseError as err:
        why = str(err).replace(str(path), "{output}")
        raise InputError(f"its output is unreadable: {why}") from None


def run_command(
    template: Template, buffers: FeatureBuffers, timeout: float = DEFAULT_TIMEOUT
) -> torch.Tensor:
    """Write ``buffers`` as the template asks, run the command in a temporary folder, and
    return its output as ``(3, H, W)`` float32.

    Raises:
        InputError: one line: what failed, the exit status, and the last stderr lines.
    """
    program = _program(template.argv[0])
    if program is None:
        raise InputError(f"command {template.text!r}: program {template.argv[0]!r} not found")
    h, w = buffers.shape
    _sweep_once()
    with tempfile.TemporaryDirectory(prefix=f"{FOLDER_PREFIX}{os.getpid()}-") as tmp:
        folder = Path(tmp)
        paths: dict[str, str] = {}
        for name, fmt in template.fields.items():
            path = folder / f"{name}.{fmt}"
            paths[name] = str(path)
            if name == "input":
                save_buffers(path, buffers)
            elif name != "output":
                _write_feature(path, buffers[name], fmt)
        argv = [program, *_absolute_args(template.fill(paths)[1:], template.argv[0])]
        launcher, preexec = _with_parent()
        out, fmt = Path(paths["output"]), template.fields["output"]
        proc = subprocess.Popen(
            [*launcher, *argv],
            cwd=folder,
            env=command_env(),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            errors="replace",
            start_new_session=True,  # the timeout ends the command's own children too
            preexec_fn=preexec,  # (or the launcher) a kill -9 of mcdenoise ends the command
        )
        watcher = _group_watcher(proc.pid)
        try:
            _, err = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            _kill(proc)
            _, err = proc.communicate()
            raise InputError(
                _failure(template, f"ran past its timeout of {timeout:g} s", err)
            ) from None
        except BaseException:  # Ctrl-C: do not leave the command running
            _kill(proc)
            proc.wait()
            raise
        finally:
            _stop_watcher(watcher)
        if proc.returncode != 0:
            raise InputError(_failure(template, f"exited with status {proc.returncode}", err))
        try:
            img = _read_output(out, fmt)
        except InputError as e:
            raise InputError(_failure(template, str(e), err)) from None
    if img.shape[1:] != (h, w):
        got = f"{img.shape[2]}x{img.shape[1]}"
        raise InputError(_failure(template, f"wrote a {got} output for a {w}x{h} input", err))
    return torch.from_numpy(img)


def _failure(template: Template, what: str, stderr: str) -> str:
    tail = _tail(stderr)
    return f"command {template.text!r}: {what}" + (f"; stderr: {tail}" if tail else "")


class CommandParams(Mapping[str, Any]):
    """The parameters of a command method (its :attr:`Method.defaults`): ``command`` (the
    template), ``version`` and ``timeout`` (:data:`DEFAULT_TIMEOUT`).

    ``version`` is what ``PROGRAM --version`` prints (:func:`program_version`), and asking
    runs the program: it is asked the first time the value is read, which is when the
    method's parameters are resolved for a denoise (:meth:`Method.resolve_params`: before
    the first frame, or when ``mcdenoise denoise`` checks ``--param``), an experiment's unit
    fingerprint, or a record. Building the method, listing the keys (``"command" in
    defaults``) or reading ``command`` runs nothing.
    """

    KEYS = ("command", "version", "timeout")

    def __init__(self, template: Template) -> None:
        self.template = template
        self._version: str | None = None

    def version(self) -> str:
        """The program's version line (asked once, then kept), ``""`` without an answer."""
        if self._version is None:
            program = _program(self.template.argv[0])
            argv = _version_argv(program, self.template.argv) if program else None
            self._version = program_version(tuple(argv)) if argv else ""
        return self._version

    def unasked(self) -> dict[str, Any]:
        """The parameters with ``version`` empty, without asking the program: for checking
        overrides (an experiment spec's ``[params.NAME]``) before anything may run."""
        return {"command": self.template.text, "version": "", "timeout": DEFAULT_TIMEOUT}

    def __getitem__(self, key: str) -> Any:
        if key == "command":
            return self.template.text
        if key == "version":
            return self.version()
        if key == "timeout":
            return DEFAULT_TIMEOUT
        raise KeyError(key)

    def __contains__(self, key: object) -> bool:
        return key in self.KEYS

    def __iter__(self) -> Iterator[str]:
        return iter(self.KEYS)

    def __len__(self) -> int:
        return len(self.KEYS)

    def __eq__(self, other: object) -> bool:  # without asking the version
        return isinstance(other, CommandParams) and other.template.text == self.template.text

    __hash__ = None  # type: ignore[assignment]  # a mapping, as a dict

    def __repr__(self) -> str:
        version = "<not asked yet>" if self._version is None else repr(self._version)
        return f"CommandParams(command={self.template.text!r}, version={version})"


def command_method(text: str, *, name: str | None = None) -> Method:
    """The per-frame :class:`~mcdenoise.method.Method` of a command template (the text after
    ``cmd:``); ``name`` defaults to :func:`method_name`. Building it runs nothing.

    Its parameters (recorded in every output's header; :class:`CommandParams`): ``command``
    (the template; fixed: another command is another method), ``version`` (``PROGRAM
    --version``, asked when the parameters are first resolved for a denoise; fixed) and
    ``timeout`` (seconds per frame).

    Raises:
        InputError: a bad template (:func:`parse_template`).
    """
    template = parse_template(text.strip())
    defaults = CommandParams(template)
    per_file = [f for f in ("albedo", "normal") if f in template.fields]
    if "input" in template.fields:
        uses = tuple(b for b in BUFFER_NAMES if b != "color" and b not in per_file)
    else:
        uses = ()

    def unavailable() -> str | None:
        if _program(template.argv[0]) is None:
            return (
                f"program {template.argv[0]!r} not found (not on PATH, or not an executable file)"
            )
        return None

    def run(b: FeatureBuffers, params: Mapping[str, Any], device: torch.device) -> torch.Tensor:
        # command and version are provenance, not settings: --param cannot change what the
        # outputs record (the version was asked when params were resolved, and is kept)
        if params["command"] != template.text or params["version"] != defaults.version():
            raise InputError(
                "the command and version of a cmd: method are fixed (what ran, and what "
                "its --version printed); only timeout can be set"
            )
        timeout = float(params["timeout"])
        if not timeout > 0:
            raise InputError(f"timeout must be > 0 seconds, got {params['timeout']!r}")
        return run_command(template, b, timeout)

    return Method(
        name=name or method_name(text),
        summary=f"external command {template.text!r}; timed as a whole process "
        "(writing its inputs, start-up, its work, reading its output)",
        requires=("color", *per_file),
        uses=uses,
        defaults=defaults,
        run=run,
        priority=-100,
        unavailable=unavailable,
        devices=("cpu", "cuda"),
    )


__all__ = [
    "DEFAULT_TIMEOUT",
    "PLACEHOLDERS",
    "PREFIX",
    "CommandParams",
    "Template",
    "command_env",
    "command_method",
    "is_interpreter",
    "method_name",
    "parse_template",
    "program_version",
    "read_pfm",
    "run_command",
    "write_pfm",
]

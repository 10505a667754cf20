"""The files of ``mcdenoise denoise``: which inputs, read how, which frames make a sequence,
and where the outputs go.

Below :mod:`mcdenoise.batch` and :mod:`mcdenoise.output`: it reads headers and names, never
runs a method.

Inputs
    :func:`collect_inputs` expands files and folders (``*.exr``, not recursive) into files;
    a folder's files that this tool wrote (header ``mcdenoise:method``, read without a pixel:
    :func:`written_by_mcdenoise`) are left out unless asked for (``--include-outputs``), so a
    re-run on a folder never denoises its own outputs again;
    :func:`collect_sequences` groups them for a temporal method: each folder one sequence,
    the files given one by one one more.
Sequences
    :func:`scan_sequence` orders and checks the frames of one sequence from their headers
    (:func:`frame_info`: buffers resolved by name through the profiles and a mapping file,
    size, frame number), so a temporal method refuses a bad sequence before anything is
    written; :func:`output_complete` says whether an output is already done (resume).
Outputs
    :func:`plan_outputs` names them, :func:`check_output_folder` and :func:`check_output_path`
    check where they go, :func:`refuse_overwriting_inputs` refuses a batch whose outputs
    would replace any of its inputs (before anything is written).
"""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcdenoise.errors import InputError, McdenoiseError
from mcdenoise.io import load_buffers, probe_exr
from mcdenoise.io.atomic import TMP_PREFIX
from mcdenoise.io.buffers import MissingFeatureError
from mcdenoise.io.exr import select_part
from mcdenoise.io.exr_layout import header_strings
from mcdenoise.io.profiles import BLENDER_ATTR, LAYOUT_ATTR, resolve_channels
from mcdenoise.method import Method

__all__ = [
    "FrameInfo",
    "ReadOptions",
    "SequenceJob",
    "WriteOptions",
    "check_output_folder",
    "check_output_path",
    "collect_inputs",
    "collect_sequences",
    "file_in_the_way",
    "frame_info",
    "make_output_folder",
    "output_complete",
    "plan_outputs",
    "plan_sequences",
    "refuse_overwriting_inputs",
    "scan_sequence",
    "written_by_mcdenoise",
]


@dataclass
class ReadOptions:
    """How input files are read (see :func:`mcdenoise.io.load_buffers`); ``include_outputs``:
    a folder's files written by this tool are inputs too (:func:`collect_inputs`)."""

    profile: str = "auto"
    mapping: str | None = None
    part: str | None = None
    spp: int | None = None
    include_outputs: bool = False


@dataclass
class WriteOptions:
    """How outputs are written: ``half`` (float16, clamped and counted) and compression;
    ``estimate_error``: also estimate the output's relMSE from the input's half buffers
    (:mod:`mcdenoise.eval.estimate`) into the header and the JSON record."""

    half: bool = False
    compression: str = "zip"
    estimate_error: bool = False


def check_output_path(src: Path, dst: Path) -> None:
    if dst.exists() and dst.is_dir():
        raise InputError(f"output {dst} is a folder; give a file name ending in .exr")
    if dst.suffix.lower() != ".exr":
        raise InputError(f"output {dst} must end in .exr")
    if src.exists() and dst.exists() and src.resolve() == dst.resolve():
        raise InputError(f"output {dst} is the input file; choose another name")
    parent = dst.parent if str(dst.parent) else Path(".")
    blocker = file_in_the_way(parent)
    if blocker is not None:
        raise InputError(f"cannot write {dst}: {blocker} is a file, not a folder")
    # A folder that does not exist yet is created when the output is written (after the
    # method succeeded, so a failed run leaves no empty folder): what must be writable is
    # the nearest folder that exists.
    existing = next((q for q in [parent, *parent.parents] if q.is_dir()), Path("."))
    if not os.access(existing, os.W_OK):
        raise InputError(f"output folder {existing} is not writable")


_EXTENSION = re.compile(r"\.[A-Za-z][A-Za-z0-9]{0,4}")


def file_in_the_way(path: str | os.PathLike[str]) -> Path | None:
    """The first of ``path``'s existing ancestors (or ``path`` itself) that is not a folder,
    else ``None``: what stops ``path`` being used or created as a folder.

    >>> file_in_the_way("no/such/folder") is None
    True
    """
    p = Path(path)
    for q in [*reversed(p.parents), p]:  # from the top down
        if not q.exists():
            return None
        if not q.is_dir():
            return q
    return None


def check_output_folder(
    path: str | os.PathLike[str], option: str = "-o", *, exr_ok: bool = False
) -> Path:
    """Check that ``path`` (the value of ``option``) can be an output folder; return it.

    ``exr_ok``: the option also takes an ``.exr`` file name (``denoise -o``), which the
    message then mentions.

    An existing folder is fine. Refused, with one line naming the cause: a file in the way
    (``text.exr is a file, not a folder``), and a new name ending in a file extension
    (``out/p.txt``), which is nearly always a file name given where a folder is wanted.

    Raises:
        InputError: as above.
    """
    p = Path(path)
    blocker = file_in_the_way(p)
    if blocker is not None:
        raise InputError(f"{option} {p}: {blocker} is a file, not a folder")
    if not p.exists() and _EXTENSION.fullmatch(p.suffix):
        what = "an output file must end in .exr and " if exr_ok else ""
        raise InputError(
            f"{option} {p}: {what}a new folder must not have a file extension like {p.suffix!r}"
        )
    return p


def make_output_folder(
    path: str | os.PathLike[str], option: str = "-o", *, exr_ok: bool = False
) -> Path:
    """:func:`check_output_folder`, then create it (and its parents)."""
    p = check_output_folder(path, option, exr_ok=exr_ok)
    p.mkdir(parents=True, exist_ok=True)
    return p


def written_by_mcdenoise(path: str | os.PathLike[str]) -> bool:
    """Whether the EXR ``path`` is an output of ``mcdenoise denoise`` (or of an experiment):
    its header has ``mcdenoise:method``. Only header bytes are read; a file whose header
    cannot be read is not an output (reading it as an input then says what is wrong)."""

    try:
        return any("mcdenoise:method" in part for part in header_strings(path))
    except McdenoiseError:
        return False


def collect_inputs(
    paths: Sequence[str | os.PathLike[str]], *, include_outputs: bool = False
) -> list[Path]:
    """Expand files and folders (``*.exr``, not recursive, sorted) into a list of EXR files.

    A folder's files written by this tool (:func:`written_by_mcdenoise`) are left out unless
    ``include_outputs``; files named one by one are always inputs.
    """

    files: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(
                q
                for q in p.iterdir()
                if q.suffix.lower() == ".exr" and q.is_file() and not q.name.startswith(TMP_PREFIX)
            )
            if not found:
                raise InputError(f"folder {p} holds no .exr files{_subfolder_hint(p)}")
            if not include_outputs:
                kept = [q for q in found if not written_by_mcdenoise(q)]
                if not kept:
                    raise InputError(
                        f"folder {p} holds only outputs of mcdenoise ({len(found)} file(s) with "
                        "the header mcdenoise:method); --include-outputs denoises them too"
                    )
                found = kept
            files.extend(found)
        elif p.exists():
            files.append(p)
        else:
            raise InputError(f"input {p} does not exist")
    if not files:
        raise InputError("no input files given")
    if len(set(f.resolve() for f in files)) != len(files):
        raise InputError("the same input file is given twice")
    return files


def _subfolder_hint(folder: Path) -> str:
    """Where the frames are when ``folder`` is the top of a ``render --frames`` output (one
    subfolder per sequence): ``" (its subfolders a, b hold some: give them, e.g. DIR/a)"``."""

    def holds_exr(q: Path) -> bool:
        try:
            return q.is_dir() and any(r.suffix.lower() == ".exr" for r in q.iterdir())
        except OSError:  # unreadable: no hint from it
            return False

    with_exr = sorted(q.name for q in folder.iterdir() if q.name != "ref" and holds_exr(q))
    if not with_exr:
        return ""
    shown = ", ".join(with_exr[:5]) + (", ..." if len(with_exr) > 5 else "")
    return f" (its subfolders {shown} hold some: give them, e.g. {folder / with_exr[0]})"


def plan_outputs(
    inputs: Sequence[Path],
    output: str | os.PathLike[str] | None,
    method_name: str,
    *,
    part: str | None = None,
) -> list[Path]:
    """Output path for each input.

    * one input and ``output`` a file name (``*.exr``) -> that file;
    * ``output`` a folder (existing, or a new name without a file extension: ``out/p.txt`` is
      refused, see :func:`check_output_folder`) -> ``folder/<stem>_<method>.exr``;
    * no ``output`` -> ``<stem>_<method>.exr`` next to each input.

    With ``part`` (a level of a multi-part file, e.g. ``spp16``) the name is
    ``<stem>_<part>_<method>.exr``, so outputs of different levels never collide.
    """
    if output is not None:
        out = Path(output)
        if out.suffix.lower() == ".exr" and not out.is_dir():
            if len(inputs) != 1:
                raise InputError(
                    f"{len(inputs)} inputs but -o {out} names one file; give a folder instead"
                )
            parent = out.parent if str(out.parent) else Path(".")
            blocker = file_in_the_way(parent)
            if blocker is not None:
                raise InputError(f"-o {out}: {blocker} is a file, not a folder")
            return [out]
        check_output_folder(out, "-o", exr_ok=True)
        folders = [out] * len(inputs)
    else:
        folders = [p.parent for p in inputs]
    tag = f"_{part}" if part else ""
    outs = [f / f"{p.stem}{tag}_{method_name}.exr" for f, p in zip(folders, inputs)]
    _refuse_same_output(outs, inputs)
    return outs


def _refuse_same_output(outs: Sequence[Path], inputs: Sequence[Path]) -> None:
    """One line naming the first two inputs whose outputs would have the same name."""
    first: dict[Path, Path] = {}
    for out, src in zip(outs, inputs):
        if out in first:
            raise InputError(f"{first[out]} and {src} would both write {out}; use separate folders")
        first[out] = src


def _entry(path: Path) -> str:
    """The folder entry ``path`` names: its folder resolved, its own name kept (a symbolic
    link is the entry a write would replace, not the file it points to)."""
    return os.path.join(os.path.realpath(path.parent if str(path.parent) else "."), path.name)


def refuse_overwriting_inputs(inputs: Sequence[Path], planned: Sequence[tuple[Path, Path]]) -> None:
    """Raise :class:`InputError` (one line) when a planned ``(input, output)`` of the batch
    would replace one of its ``inputs``: the same folder entry, or an existing output that is
    the same file (``denoise coll -o coll -m nlm`` where ``coll`` holds ``a.exr`` and
    ``a_nlm.exr``). Called when the batch is planned, before anything is read or written.
    """
    by_entry = {_entry(p): p for p in inputs}
    by_inode: dict[tuple[int, int], Path] = {}
    for p in inputs:
        with contextlib.suppress(OSError):
            st = p.stat()
            by_inode[(st.st_dev, st.st_ino)] = p
    for src, out in planned:
        hit = by_entry.get(_entry(out))
        if hit is None and by_inode:
            with contextlib.suppress(OSError):
                st = out.stat()
                hit = by_inode.get((st.st_dev, st.st_ino))
        if hit is not None and hit == src:  # -o names the input itself (or a link to it)
            raise InputError(
                f"{src}: its output {out} would overwrite this input; nothing was written: "
                "give -o another file name or a folder"
            )
        if hit is not None:
            raise InputError(
                f"{hit} is an input of this batch and the output of {src} would overwrite it; "
                "nothing was written: write the outputs into another folder (-o)"
            )


# --- sequences: the frames of a folder for a temporal method --------------------------------

#: The frame number in a file name when the header records none: the last run of digits
#: (``frame_0012.exr``, ``shot.0012.exr``, ``0012.exr``).
_NAME_NUMBER = re.compile(r"(\d+)\D*$")


@dataclass(frozen=True)
class FrameInfo:
    """What the headers of one frame file say; no pixel is read (:func:`frame_info`)."""

    path: Path
    buffers: frozenset[str]  # the buffers the profile (and mapping) would read
    size: tuple[int, int]  # (width, height) of the data window read
    number: int | None  # mcdenoise:frame, else the last number in the file name
    sequence: str | None  # mcdenoise:sequence (the render's id), when recorded
    denoised: bool  # a denoiser's output (its header records mcdenoise:method)


def frame_info(path: str | os.PathLike[str], read: ReadOptions | None = None) -> FrameInfo:
    """The buffers, size and frame number of one frame, from its headers only.

    The buffers are what :func:`mcdenoise.io.load_buffers` with ``read`` would produce: the
    file's channels resolved by name through the profile (detected or ``read.profile``) and
    ``read.mapping``, e.g. ``motion`` from the canonical ``motion.X/Y``, from Cycles'
    ``Vector`` pass, or from the channels a mapping file names. A Blender file of one part per
    pass (whose view layer spans parts), or one read with ``read.part`` (a view layer by
    name), is read in full instead, by the loader itself.

    Raises:
        ExrError, ProfileError, MissingFeatureError: as :func:`mcdenoise.io.load_buffers`.
    """

    read = read or ReadOptions()
    p = Path(path)
    parts = probe_exr(p)
    attributes: dict[str, Any] = {}
    if BLENDER_ATTR in parts[0].attributes and (len(parts) > 1 or read.part is not None):
        # a view layer may span parts, and --part may name a layer: the loader's own rules

        fb = load_buffers(
            p, profile=read.profile, mapping=read.mapping, part=read.part, spp=read.spp
        )
        names = frozenset(fb.names())
        h, w = fb.shape
        attributes = fb.attributes
    else:
        part = read.part
        if part is None and len(parts) > 1 and all(LAYOUT_ATTR in q.attributes for q in parts):
            part = 0  # as the loader: every part is a complete image (spp levels), the first
        searched = parts if part is None else [select_part(parts, part, str(p))]
        channels: dict[str, int] = {}
        for q in searched:
            for c in q.channel_names:
                channels.setdefault(c, q.index)
        for q in reversed(searched):  # the first part wins, as in the loader
            attributes.update(q.attributes)
        cmap = resolve_channels(
            list(channels),
            attributes,
            profile=read.profile,
            mapping=read.mapping,
            spp=read.spp,
            strict=True,
            source=str(p),
        )
        names = frozenset(cmap.sources)
        colour = cmap.sources["color"][0].file_channels()[0]
        owner = parts[channels[colour]]
        w, h = owner.width, owner.height
    number: int | None = None
    recorded = attributes.get("mcdenoise:frame")
    if isinstance(recorded, int) and not isinstance(recorded, bool):
        number = recorded
    else:
        found = _NAME_NUMBER.search(p.stem)
        number = int(found.group(1)) if found else None
    seq = attributes.get("mcdenoise:sequence")
    return FrameInfo(
        p,
        names,
        (w, h),
        number,
        str(seq) if seq is not None else None,
        "mcdenoise:method" in attributes,
    )


@dataclass(frozen=True)
class SequenceJob:
    """The frames of one sequence, denoised in order by one temporal method.

    ``source`` is the folder the frames came from (or the first of the files given one by
    one), ``inputs`` the frames in order and ``outputs`` one file each; ``skipped`` (with
    ``--method all``) why the method refuses this sequence.
    """

    source: Path
    inputs: tuple[Path, ...]
    outputs: tuple[Path, ...]
    method: Method
    numbers: tuple[int | None, ...] = ()
    skipped: str | None = None


def collect_sequences(
    paths: Sequence[str | os.PathLike[str]], *, include_outputs: bool = False
) -> list[tuple[Path, list[Path]]]:
    """Group the inputs into sequences: each folder is one (its ``*.exr`` as in
    :func:`collect_inputs`; ``ref/`` and other subfolders are not read), and the files given
    one by one are one more, together. Returns ``(source, files)`` per sequence."""
    collect_inputs(paths, include_outputs=include_outputs)  # the same checks
    groups: list[tuple[Path, list[Path]]] = []
    loose: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            groups.append((p, collect_inputs([p], include_outputs=include_outputs)))
        else:
            loose.append(p)
    if loose:
        groups.append((loose[0], loose))
    return groups


def scan_sequence(
    source: Path, files: Sequence[Path], method: Method, read: ReadOptions | None = None
) -> list[FrameInfo]:
    """The frames of one sequence in order, checked for a temporal ``method``; only headers
    are read.

    Files a denoiser wrote (``mcdenoise:method`` in the header: outputs written beside the
    frames) are not frames and are left out. The order is the frame number: the header's
    ``mcdenoise:frame`` (``mcdenoise render --frames``), else the last number in the file
    name.

    Raises:
        InputError: one line naming the problem: no frames; a frame without a number (in a
            sequence of several); two files of one frame number; a gap in the numbering;
            frames of different sizes or of different recorded sequences; a frame without
            ``motion`` (a sequence of several frames: the method's history cannot follow
            what moves; the message says how to map the channels); a frame without a buffer
            the method requires.
    """
    where = str(source)
    frames = [f for f in (frame_info(p, read) for p in files) if not f.denoised]
    if not frames:
        raise InputError(f"{where}: no frames to denoise (only denoised outputs)")
    if len(frames) > 1:
        unnumbered = [f.path.name for f in frames if f.number is None]
        if unnumbered:
            raise InputError(
                f"{where}: {unnumbered[0]} has no frame number (no mcdenoise:frame in its "
                "header, no number in its name); the frames of a sequence are ordered by it"
            )
        frames.sort(key=lambda f: (f.number, f.path.name))
        for a, b in itertools.pairwise(frames):
            assert a.number is not None and b.number is not None
            if a.number == b.number:
                raise InputError(
                    f"{where}: {a.path.name} and {b.path.name} are both frame {a.number}"
                )
            if b.number != a.number + 1:
                missing = (
                    f"frame {a.number + 1} is missing"
                    if b.number == a.number + 2
                    else f"frames {a.number + 1}-{b.number - 1} are missing"
                )
                raise InputError(
                    f"{where}: {missing} (between {a.path.name} and {b.path.name}); "
                    "a temporal method needs consecutive frames"
                )
    sizes = {f.size for f in frames}
    if len(sizes) > 1:
        a = frames[0]
        b = next(f for f in frames if f.size != a.size)
        raise InputError(
            f"{where}: frames of different sizes: {a.path.name} is {a.size[0]}x{a.size[1]}, "
            f"{b.path.name} is {b.size[0]}x{b.size[1]}"
        )
    seqs = {f.sequence for f in frames if f.sequence is not None}
    if len(seqs) > 1:
        raise InputError(
            f"{where}: frames of different sequences ({', '.join(sorted(seqs))}, by their "
            "mcdenoise:sequence header)"
        )
    for f in frames:
        if len(frames) > 1 and "motion" not in f.buffers:
            have = ", ".join(sorted(f.buffers))
            raise InputError(
                f"{where}: method {method.name!r} needs motion vectors in every frame; "
                f"{f.path.name} has none (it has {have}; map its channels with --mapping)"
            )
        missing = [r for r in method.requires if r not in f.buffers]
        if missing:
            raise MissingFeatureError(
                missing, sorted(f.buffers), source=str(f.path), needed_by=f"method {method.name!r}"
            )
    return frames


def output_complete(
    output: Path,
    source: Path,
    method: Method,
    params: Mapping[str, Any],
    part: str | None,
) -> bool:
    """Whether ``output`` is a finished output of ``source`` by ``method`` with ``params``
    (and ``part``): it exists, its header reads, and records that method, those parameters
    and that source. Outputs are written atomically, so a file that exists is whole; the
    header says whether it is this run's."""

    if not output.is_file():
        return False
    try:
        attrs = probe_exr(output)[0].attributes
    except McdenoiseError:
        return False
    return (
        attrs.get("mcdenoise:method") == method.name
        and attrs.get("mcdenoise:params") == json.dumps(dict(params), sort_keys=True)
        and attrs.get("mcdenoise:source") == str(source.resolve())
        and attrs.get("mcdenoise:source_part") == (None if part is None else str(part))
    )


def plan_sequences(
    inputs: Sequence[str | os.PathLike[str]],
    output: str | os.PathLike[str] | None,
    m: Method,
    read: ReadOptions,
    part: str | None,
    *,
    skip: bool,
) -> list[SequenceJob]:
    """The :class:`SequenceJob` of the temporal method ``m`` for each sequence of
    ``inputs`` (:func:`collect_sequences`), checked by :func:`scan_sequence`; with ``skip``
    (``--method all``) a sequence ``m`` refuses is recorded as skipped, with the reason."""
    jobs: list[SequenceJob] = []
    for source, files in collect_sequences(inputs, include_outputs=read.include_outputs):
        try:
            frames = scan_sequence(source, files, m, read)
        except InputError as err:
            if not skip:
                raise
            jobs.append(SequenceJob(source, tuple(files), (), m, skipped=str(err)))
            continue
        paths = [f.path for f in frames]
        outs = plan_outputs(paths, output, m.name, part=part)
        jobs.append(
            SequenceJob(source, tuple(paths), tuple(outs), m, tuple(f.number for f in frames))
        )
    pairs = [(o, Path(i)) for j in jobs for o, i in zip(j.outputs, j.inputs)]  # not skipped
    _refuse_same_output([o for o, _ in pairs], [i for _, i in pairs])
    return jobs

"""Fuzz ``mcdenoise info`` and ``mcdenoise denoise`` with corrupted EXR files; tally how they fail.

Makes ``--n`` corrupted variants of the sample files (``data/samples/*.exr`` and
``data/samples/ref/*.exr``), seeded and reproducible (variant ``i`` depends only on
``--seed`` and ``i``), runs ``mcdenoise info FILE`` and ``mcdenoise denoise FILE -o OUT``
on each as a child process with a time limit, and tallies per command:

* ``ok`` / ``clean error`` (exit 1, one ``mcdenoise: error: ...`` line on stderr);
* ``internal error`` (the CLI's one-line report of a bug), ``traceback`` (a Python traceback
  reached the user), ``crash`` (killed by a signal), ``timeout`` (over ``--timeout``),
  ``other`` (any other non-zero exit);
* message defects: ``undecodable`` (the message says it could not decode the library's
  text), ``api names`` (a Python name such as ``mcdenoise.io.buffers.sanitize`` or
  ``max_pixels=`` in a message for a command-line user), ``multi-line`` (more than one line
  on stderr), ``half-written`` (a failed ``denoise`` left an output or temporary file);
* ``info ok, denoise fails``: ``info`` exits 0 but ``denoise`` fails; ``silent`` when ``info``
  printed no problem line (``PROBLEM``) that would have warned the user;
* seconds and peak resident memory of each child (``os.wait4``'s ``ru_maxrss``; the largest
  over all children is also ``resource.getrusage(RUSAGE_CHILDREN).ru_maxrss``), with the
  slowest failures listed.

Corruptions (one per variant, chosen uniformly): byte flips in the header, in the pixel data
and in the chunk offset table; truncation; ``dataWindow`` edits (huge windows such as
100000x128, inverted or shifted ones); ``displayWindow`` edits; swapped channel pixel types;
channel names with bytes that are not UTF-8; another compression value; corrupted attribute
values and attribute sizes.

Children are, by default, forked from this process after it has imported the CLI (so each
run skips the ~2 s import of torch); each child is still a separate process with its own
stdout, stderr, exit status, signals and memory. ``--exec`` starts ``python -c 'mcdenoise'``
afresh for each run instead (slower; peak memory then includes the interpreter start).
To fuzz another checkout (e.g. the code before a fix), put it first on ``PYTHONPATH`` with a
``mcdenoise_cli`` link to its ``cli`` folder.

    python benchmarks/fuzz_exr.py --n 400 --seed 0 [--jobs 2] [--timeout 60]
        [--method cross-bilateral] [--workdir DIR] [--json out.json] [--markdown]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import resource
import signal
import struct
import sys
import tempfile
import time
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MUTATIONS = (
    "flip_header",
    "flip_data",
    "flip_offsets",
    "truncate",
    "data_window_huge",
    "data_window_edit",
    "display_window_edit",
    "channel_type",
    "channel_name",
    "compression",
    "attr_value",
    "attr_size",
)
# Scanlines per chunk of each compression (OpenEXR enum order).
_LINES_PER_CHUNK = (1, 1, 1, 16, 32, 16, 32, 32, 32, 256)
_API_NAMES = re.compile(
    r"mcdenoise\.(io|filters|prep|methods|models|errors)\b|io\.buffers|\bsanitize\b"
    r"|(?<![-\w])(max_pixels|max_bytes|part|spp|mapping|profile)=(?!\w)"
)
_BOOT = (
    "import sys; sys.argv[0] = 'mcdenoise'; "
    "from mcdenoise_cli.main import main; sys.exit(main(prog_name='mcdenoise'))"
)


# --- EXR layout ------------------------------------------------------------------------------
@dataclass
class Attr:
    name: str
    type: str
    start: int  # offset of the attribute's name
    size_at: int  # offset of its 4-byte size
    value_at: int  # offset of its value
    size: int


@dataclass
class Layout:
    headers: list[dict[str, Attr]]
    header_end: int  # first byte after the header(s): the chunk offset table
    chunks: int  # entries of the offset table (first part)


def parse_layout(data: bytes) -> Layout:
    """Positions of the header attributes and of the offset table of an intact EXR file."""
    version = struct.unpack_from("<i", data, 4)[0]
    multipart = bool(version & 0x1000)
    pos = 8
    headers: list[dict[str, Attr]] = []
    while True:
        attrs: dict[str, Attr] = {}
        while data[pos] != 0:
            name_end = data.index(b"\0", pos)
            type_end = data.index(b"\0", name_end + 1)
            size = struct.unpack_from("<i", data, type_end + 1)[0]
            name = data[pos:name_end].decode("latin-1")
            attrs[name] = Attr(
                name,
                data[name_end + 1 : type_end].decode("latin-1"),
                pos,
                type_end + 1,
                type_end + 5,
                size,
            )
            pos = type_end + 5 + size
        pos += 1
        headers.append(attrs)
        if not multipart or data[pos] == 0:
            pos += multipart
            break
    h = headers[0]
    y0, y1 = (
        struct.unpack_from("<i", data, h["dataWindow"].value_at + 4)[0],
        struct.unpack_from("<i", data, h["dataWindow"].value_at + 12)[0],
    )
    comp = data[h["compression"].value_at]
    if "chunkCount" in h:
        chunks = struct.unpack_from("<i", data, h["chunkCount"].value_at)[0]
    else:
        per = _LINES_PER_CHUNK[comp] if comp < len(_LINES_PER_CHUNK) else 1
        chunks = -(-(y1 - y0 + 1) // per)
    return Layout(headers, pos, chunks)


def _channel_entries(data: bytes, attr: Attr) -> list[tuple[int, int]]:
    """(name offset, pixel-type offset) of each channel of a ``chlist`` attribute."""
    out, pos, end = [], attr.value_at, attr.value_at + attr.size
    while pos < end and data[pos] != 0:
        name_end = data.index(b"\0", pos)
        out.append((pos, name_end + 1))
        pos = name_end + 1 + 16
    return out


# --- mutations -----------------------------------------------------------------------------
def mutate(data: bytes, kind: str, rng: random.Random) -> tuple[bytes, str]:
    """One corrupted copy of ``data`` and a short description of what was changed."""
    buf = bytearray(data)
    lay = parse_layout(data)
    h = lay.headers[0]
    end = lay.header_end
    if kind == "flip_header":
        spots = [rng.randrange(8, end) for _ in range(rng.randint(1, 4))]
        for s in spots:
            buf[s] = rng.randrange(256)
        return bytes(buf), f"header bytes {spots}"
    if kind == "flip_data":
        start = end + 8 * lay.chunks
        spots = sorted(rng.randrange(start, len(buf)) for _ in range(rng.randint(1, 16)))
        for s in spots:
            buf[s] ^= 1 << rng.randrange(8)
        return bytes(buf), f"{len(spots)} data bit flips from {spots[0]}"
    if kind == "flip_offsets":
        k = rng.randrange(lay.chunks)
        at = end + 8 * k
        old = struct.unpack_from("<Q", buf, at)[0]
        new = rng.choice(
            [rng.randrange(2**64), old + rng.randint(-64, 64), len(buf) + rng.randint(0, 10**6), 0]
        )
        struct.pack_into("<Q", buf, at, new % 2**64)
        return bytes(buf), f"offset {k}: {old} -> {new % 2**64}"
    if kind == "truncate":
        cut = rng.randrange(8, end) if rng.random() < 0.4 else rng.randrange(end, len(buf))
        return bytes(buf[:cut]), f"truncated at {cut} of {len(buf)}"
    if kind in ("data_window_huge", "data_window_edit", "display_window_edit"):
        attr = h["displayWindow" if kind == "display_window_edit" else "dataWindow"]
        x0, y0, x1, y1 = struct.unpack_from("<4i", buf, attr.value_at)
        if kind == "data_window_huge":
            choice = rng.choice(["wide", "tall", "both", "overflow"])
            if choice == "wide":
                x1 = x0 + 100_000 - 1
            elif choice == "tall":
                y1 = y0 + 100_000 - 1
            elif choice == "both":
                x1, y1 = x0 + 50_000 - 1, y0 + 50_000 - 1
            else:
                x0, x1 = -(2**31) + 1, 2**31 - 1
        else:
            choice = rng.choice(["inverted", "shift", "grow", "shrink", "negative"])
            if choice == "inverted":
                x0, x1 = x1, x0
            elif choice == "shift":
                d = rng.randint(-1000, 1000)
                x0, x1 = x0 + d, x1 + d
            elif choice == "grow":
                x1, y1 = x1 + rng.randint(1, 64), y1 + rng.randint(1, 64)
            elif choice == "shrink":
                x1, y1 = x1 - rng.randint(1, 64), y1 - rng.randint(1, 64)
            else:
                y0 = -rng.randint(1, 10**6)
        struct.pack_into("<4i", buf, attr.value_at, x0, y0, x1, y1)
        return bytes(buf), f"{attr.name} {choice} -> ({x0},{y0})-({x1},{y1})"
    if kind == "channel_type":
        entries = _channel_entries(data, h["channels"])
        picked = rng.sample(entries, min(len(entries), rng.randint(1, 3)))
        done = []
        for name_at, type_at in picked:
            old = struct.unpack_from("<i", buf, type_at)[0]
            new = rng.choice([t for t in (0, 1, 2) if t != old] + [3, 255])
            struct.pack_into("<i", buf, type_at, new)
            done.append(f"{data[name_at : type_at - 1].decode('latin-1')}:{old}->{new}")
        return bytes(buf), "pixel types " + ", ".join(done)
    if kind == "channel_name":
        name_at, type_at = rng.choice(_channel_entries(data, h["channels"]))
        old = data[name_at : type_at - 1].decode("latin-1")
        k = name_at + rng.randrange(type_at - 1 - name_at)
        buf[k] = rng.choice([rng.randrange(0x80, 0x100), rng.randrange(0x61, 0x7B)])
        return bytes(buf), f"channel {old!r} byte {k - name_at} -> {buf[k]:#04x}"
    if kind == "compression":
        old = buf[h["compression"].value_at]
        new = rng.choice([c for c in range(10) if c != old] + [10, 42, 255])
        buf[h["compression"].value_at] = new
        return bytes(buf), f"compression {old} -> {new}"
    if kind == "attr_value":
        structural = {"channels", "compression", "dataWindow", "displayWindow", "lineOrder"}
        attr = rng.choice([a for a in h.values() if a.name not in structural and a.size > 0])
        spots = [attr.value_at + rng.randrange(attr.size) for _ in range(rng.randint(1, 3))]
        for s in spots:
            buf[s] = rng.choice([rng.randrange(0x80, 0x100), rng.randrange(256), 0])
        return bytes(buf), f"attribute {attr.name} ({attr.type}) value bytes {spots}"
    if kind == "attr_size":
        attr = rng.choice(list(h.values()))
        new = rng.choice([attr.size + rng.randint(-8, 8), -1, 2**31 - 1, rng.randrange(2**31)])
        struct.pack_into("<i", buf, attr.size_at, new)
        return bytes(buf), f"attribute {attr.name} size {attr.size} -> {new}"
    raise ValueError(kind)


def make_variants(n: int, seed: int, sources: list[Path], folder: Path) -> list[dict]:
    """``n`` corrupted files in ``folder``; variant ``i`` depends on (seed, i) only."""
    folder.mkdir(parents=True, exist_ok=True)
    blobs = {p: p.read_bytes() for p in sources}
    cases = []
    for i in range(n):
        rng = random.Random(f"{seed}:{i}")
        src = rng.choice(sources)
        kind = rng.choice(MUTATIONS)
        data, what = mutate(blobs[src], kind, rng)
        path = folder / f"fuzz_{i:04d}_{kind}.exr"
        path.write_bytes(data)
        cases.append(
            {"index": i, "file": str(path), "source": src.name, "kind": kind, "what": what}
        )
    return cases


# --- running -------------------------------------------------------------------------------
@dataclass
class Run:
    case: int
    command: str  # "info" or "denoise"
    rc: int | None = None
    signal: int | None = None
    timed_out: bool = False
    seconds: float = 0.0
    maxrss_mb: float = 0.0
    stdout: str = ""
    stderr: str = ""
    leftovers: list[str] = field(default_factory=list)


def _start(args: list[str], out: Path, err: Path, cwd: Path, exec_mode: bool) -> int:
    sys.stdout.flush()
    sys.stderr.flush()
    if exec_mode:
        import subprocess

        with out.open("wb") as fo, err.open("wb") as fe:
            proc = subprocess.Popen(
                [sys.executable, "-c", _BOOT, *args],
                stdout=fo,
                stderr=fe,
                cwd=cwd,
                stdin=subprocess.DEVNULL,
            )
        proc.returncode = 0  # reaped with os.wait4 below, not by Popen
        return proc.pid
    pid = os.fork()
    if pid:
        return pid
    code = 1
    try:  # the child: run the CLI with its streams redirected, never return
        os.chdir(cwd)
        for fd, path in ((1, out), (2, err)):
            f = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            os.dup2(f, fd)
            os.close(f)
        devnull = os.open(os.devnull, os.O_RDONLY)
        os.dup2(devnull, 0)
        from mcdenoise_cli.main import main

        sys.argv = ["mcdenoise", *args]
        try:
            main(args=args, prog_name="mcdenoise")
            code = 0
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
            if isinstance(e.code, str):
                print(e.code, file=sys.stderr)
    except BaseException:  # what Python itself would print for an uncaught exception
        import traceback

        traceback.print_exc()
        code = 1
    finally:
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(code)


def run_all(
    jobs: list[tuple[Run, list[str], Path]],
    workers: int,
    timeout: float,
    exec_mode: bool,
    logdir: Path,
    progress: bool,
) -> None:
    pending = list(jobs)
    running: dict[int, tuple[Run, float, Path]] = {}
    done = 0
    while pending or running:
        while pending and len(running) < workers:
            run, args, cwd = pending.pop(0)
            tag = f"{run.case:04d}_{run.command}"
            out, err = logdir / f"{tag}.out", logdir / f"{tag}.err"
            pid = _start(args, out, err, cwd, exec_mode)
            running[pid] = (run, time.perf_counter(), cwd)
        time.sleep(0.01)
        for pid in list(running):
            run, start, cwd = running[pid]
            got, status, usage = os.wait4(pid, os.WNOHANG)
            if not got:
                if time.perf_counter() - start > timeout:
                    os.kill(pid, signal.SIGKILL)
                    run.timed_out = True
                    got, status, usage = os.wait4(pid, 0)
                else:
                    continue
            run.seconds = time.perf_counter() - start
            run.maxrss_mb = usage.ru_maxrss / 1024
            if os.WIFSIGNALED(status):
                run.signal = os.WTERMSIG(status)
            else:
                run.rc = os.WEXITSTATUS(status)
            tag = f"{run.case:04d}_{run.command}"
            run.stdout = (logdir / f"{tag}.out").read_text(errors="replace")
            run.stderr = (logdir / f"{tag}.err").read_text(errors="replace")
            del running[pid]
            done += 1
            if progress and sys.stderr.isatty():
                print(f"\r{done}/{len(jobs)} runs", end="", file=sys.stderr, flush=True)
    if progress and sys.stderr.isatty():
        print(file=sys.stderr)


# --- tally ---------------------------------------------------------------------------------
def classify(run: Run) -> str:
    if run.timed_out:
        return "timeout"
    if run.signal is not None:
        return "crash"
    if run.rc == 0:
        return "ok"
    if "Traceback (most recent call last)" in run.stderr:
        return "traceback"
    if "mcdenoise: internal error" in run.stderr:
        return "internal error"
    if run.rc == 1 and any(ln.startswith("mcdenoise: error: ") for ln in run.stderr.splitlines()):
        return "clean error"
    return "other"


def error_line(run: Run) -> str:
    lines = [ln for ln in run.stderr.splitlines() if ln.startswith("mcdenoise: ")]
    return lines[-1] if lines else (run.stderr.strip().splitlines() or [""])[-1]


def _info_warned(run: Run) -> bool:
    return any(ln.lstrip().upper().startswith("PROBLEM") for ln in run.stdout.splitlines())


def tally(cases: list[dict], runs: list[Run]) -> dict:
    by = {(r.case, r.command): r for r in runs}
    out: dict = {"files": len(cases), "commands": {}}
    for cmd in ("info", "denoise"):
        rs = [r for r in runs if r.command == cmd]
        classes = Counter(classify(r) for r in rs)
        failed = [r for r in rs if r.rc != 0]
        msgs = [error_line(r) for r in failed]
        out["commands"][cmd] = {
            "runs": len(rs),
            **{
                k: classes.get(k, 0)
                for k in (
                    "ok",
                    "clean error",
                    "internal error",
                    "traceback",
                    "crash",
                    "timeout",
                    "other",
                )
            },
            "undecodable": sum("undecodable" in m for m in msgs),
            "api names": sum(bool(_API_NAMES.search(m)) for m in msgs),
            "multi-line": sum(
                len([ln for ln in r.stderr.splitlines() if ln.strip()]) > 1 for r in failed
            ),
            "half-written": sum(bool(r.leftovers) for r in failed),
            "max seconds": round(max((r.seconds for r in rs), default=0.0), 2),
            "max seconds of a failure": round(max((r.seconds for r in failed), default=0.0), 2),
            "failures over 1 s": sum(r.seconds > 1.0 for r in failed),
            "max peak RSS MB": round(max((r.maxrss_mb for r in rs), default=0.0)),
            "max peak RSS MB of a failure": round(max((r.maxrss_mb for r in failed), default=0.0)),
        }
    both = [(by[(c["index"], "info")], by[(c["index"], "denoise")]) for c in cases]
    bad = [(i, d) for i, d in both if i.rc == 0 and d.rc != 0 and not d.timed_out]
    out["info ok, denoise fails"] = len(bad)
    out["info ok, denoise fails, info silent"] = sum(not _info_warned(i) for i, _ in bad)
    out["children peak RSS MB (getrusage)"] = round(
        resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    )
    return out


def message_catalogue(cases: list[dict], runs: list[Run]) -> list[tuple[int, str]]:
    """Distinct failure messages (file path replaced by FILE, numbers by N) with counts."""
    files = {c["index"]: c["file"] for c in cases}
    counts: Counter[str] = Counter()
    for r in runs:
        if r.rc == 0:
            continue
        m = error_line(r).replace(files[r.case], "FILE")
        m = re.sub(r"\d[\d,.]*", "N", m)
        counts[f"[{r.command}] {m[:160]}"] += 1
    return [(n, m) for m, n in counts.most_common()]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=400, help="number of corrupted files")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=2, help="children running at once")
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds per run")
    ap.add_argument(
        "--method", default="auto", help="method for denoise (default: auto, as a user)"
    )
    ap.add_argument("--workdir", type=Path, default=None, help="keep files and logs here")
    ap.add_argument(
        "--exec",
        dest="exec_mode",
        action="store_true",
        help="start a fresh interpreter per run instead of forking",
    )
    ap.add_argument("--json", type=Path, default=None, help="write every run here")
    ap.add_argument("--markdown", action="store_true", help="print the tally as Markdown")
    ap.add_argument("--messages", type=int, default=25, help="distinct messages to print")
    ap.add_argument("--samples", nargs="*", type=Path, default=None)
    a = ap.parse_args()

    os.environ.setdefault("OMP_NUM_THREADS", "1")  # children share the machine
    os.environ.setdefault("MKL_NUM_THREADS", "1")
    if not a.exec_mode:  # import once; children are forked from here
        import importlib

        for mod in (
            "torch",
            "OpenImageIO",
            "mcdenoise_cli.main",
            "mcdenoise.io.info",
            "mcdenoise.denoise",
            "mcdenoise.batch",
            "mcdenoise.registry",
        ):
            importlib.import_module(mod)

    work = a.workdir or Path(tempfile.mkdtemp(prefix="mcdenoise-fuzz-"))
    sources = a.samples or sorted((ROOT / "data/samples").glob("*.exr")) + sorted(
        (ROOT / "data/samples/ref").glob("*.exr")
    )
    cases = make_variants(a.n, a.seed, sources, work / "files")
    logdir = work / "logs"
    logdir.mkdir(exist_ok=True)
    jobs: list[tuple[Run, list[str], Path]] = []
    runs: list[Run] = []
    for c in cases:
        outdir = work / "out" / f"{c['index']:04d}"
        outdir.mkdir(parents=True, exist_ok=True)
        c["outdir"] = str(outdir)
        for cmd, args in (
            ("info", ["info", c["file"]]),
            ("denoise", ["denoise", c["file"], "-o", str(outdir / "out.exr"), "-m", a.method]),
        ):
            r = Run(c["index"], cmd)
            runs.append(r)
            jobs.append((r, args, outdir))
    t0 = time.perf_counter()
    run_all(jobs, max(1, a.jobs), a.timeout, a.exec_mode, logdir, progress=True)
    wall = time.perf_counter() - t0
    for r in runs:
        if r.command == "denoise" and r.rc != 0:
            r.leftovers = sorted(p.name for p in Path(cases[r.case]["outdir"]).iterdir())

    result = tally(cases, runs)
    result["wall seconds"] = round(wall, 1)
    result["seed"], result["method"] = a.seed, a.method
    result["mode"] = "exec" if a.exec_mode else "fork"
    slow = sorted((r for r in runs if r.rc != 0), key=lambda r: -r.seconds)[:5]
    result["slowest failures"] = [
        {
            "case": r.case,
            "command": r.command,
            "kind": cases[r.case]["kind"],
            "what": cases[r.case]["what"],
            "seconds": round(r.seconds, 2),
            "peak RSS MB": round(r.maxrss_mb),
            "message": error_line(r)[:200],
        }
        for r in slow
    ]
    bad = [
        c
        for c in cases
        if runs[2 * c["index"]].rc == 0 and runs[2 * c["index"] + 1].rc not in (0, None)
    ]
    result["info ok, denoise fails: cases"] = [
        {
            "case": c["index"],
            "kind": c["kind"],
            "what": c["what"],
            "info warned": _info_warned(runs[2 * c["index"]]),
            "denoise": error_line(runs[2 * c["index"] + 1])[:200],
        }
        for c in bad
    ]
    catalogue = message_catalogue(cases, runs)
    if a.json:
        a.json.write_text(
            json.dumps(
                {
                    "tally": result,
                    "cases": cases,
                    "runs": [asdict(r) for r in runs],
                    "messages": catalogue,
                },
                indent=1,
            )
        )
    print_report(result, catalogue[: a.messages], a.markdown, work)


def print_report(
    result: dict, catalogue: list[tuple[int, str]], markdown: bool, work: Path
) -> None:
    cmds = result["commands"]
    keys = list(next(iter(cmds.values())))
    if markdown:
        print("| | " + " | ".join(cmds) + " |")
        print("|---|" + "---:|" * len(cmds))
        for k in keys:
            print(f"| {k} | " + " | ".join(str(cmds[c][k]) for c in cmds) + " |")
    else:
        print(f"{'':30}" + "".join(f"{c:>10}" for c in cmds))
        for k in keys:
            print(f"{k:30}" + "".join(f"{cmds[c][k]!s:>10}" for c in cmds))
    for k, v in result.items():
        if k in ("commands", "slowest failures", "info ok, denoise fails: cases"):
            continue
        print(f"{k}: {v}")
    print("slowest failures:")
    for s in result["slowest failures"]:
        print(
            f"  #{s['case']} {s['command']} {s['kind']} ({s['what']}): {s['seconds']} s, "
            f"{s['peak RSS MB']} MB: {s['message']}"
        )
    print("info ok, denoise fails:")
    for s in result["info ok, denoise fails: cases"]:
        warned = "info warned" if s["info warned"] else "info silent"
        print(f"  #{s['case']} {s['kind']} ({s['what']}) [{warned}]: {s['denoise']}")
    print("messages (count, normalised):")
    for n, m in catalogue:
        print(f"  {n:4d}  {m}")
    print(f"files and logs: {work}")


if __name__ == "__main__":
    main()

"""The default method on a 3840×2160 frame: seconds and peak memory against OIDN (issue 21).

Target: whatever the default is, <= 4 GB peak and no slower than 3× OIDN on a 3840×2160
frame. This script makes 4K inputs from a 128² sample render (``data/samples/cornell_spp4.exr``
by default: 4 spp, every buffer with its variance) tiled to 3840×2160 (its own 4-spp noise,
repeated), in two layouts:

* ``full``: every buffer and its variance (what ``mcdenoise render`` writes); the default is
  then ``kalantari-xbf``;
* ``novar``: the same without any variance, as a plain Mitsuba ``aov`` file or a Cycles file
  has them; the default is then ``kpcn`` (the Kalantari models refuse inputs without guide
  variances, see docs/methods.md).

For each layout it runs, each in its own process, the no-flag default

    mcdenoise denoise IN.exr -o OUT.exr --json --threads N

and ``--method oidn``, and prints per run the whole process's wall seconds, the method's own
seconds (the ``seconds`` of the ``--json`` record: no start-up, reading or writing), the peak
resident memory of the process (``ru_maxrss`` from ``os.wait4``) and the ratios to OIDN.

    python benchmarks/bench_4k.py [--threads 2] [--layouts full,novar] [--sample FILE]
        [--timeout 600] [--keep DIR] [--size 3840x2160] [--methods M1,M2]

``--methods`` also runs those methods (``--method M``) on each layout, after the default;
``M:KEY=VALUE[:KEY=VALUE]`` adds method parameters (``-p KEY=VALUE``), e.g.
``--methods kpcn:prefilter=all`` to time a ``kpcn`` variant beside the default.

A run longer than ``--timeout`` seconds is stopped and reported as such. The inputs are written
to a temporary folder (``--keep DIR``: there, and reused when present).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SAMPLE = ROOT / "data" / "samples" / "cornell_spp4.exr"
WIDTH, HEIGHT = 3840, 2160
LIMIT_GB, LIMIT_RATIO = 4.0, 3.0


def make_input(sample: Path, dst: Path, layout: str, size: tuple[int, int]) -> Path:
    """``sample`` tiled to ``size`` (W, H), all its buffers (``full``) or no variances
    (``novar``)."""
    if dst.is_file():
        return dst
    import torch

    from mcdenoise.io import FeatureBuffers, load_buffers, save_buffers

    torch.set_num_threads(1)
    src = load_buffers(sample)
    h, w = src.shape
    width, height = size
    reps = (-(-height // h), -(-width // w))
    keep = [n for n in src.names() if layout == "full" or not n.endswith("_var")]
    bufs = {n: src[n].repeat(1, *reps)[:, :height, :width].contiguous() for n in keep}
    save_buffers(dst, FeatureBuffers(bufs, spp=src.spp))
    return dst


def run(args: list[str], timeout: float) -> dict:
    """Run ``mcdenoise`` with ``args`` in a child; wall seconds, peak RSS and its JSON record."""
    cmd = [sys.executable, "-m", "mcdenoise_cli.main", *args]
    start = time.perf_counter()
    # files, not pipes: the child never blocks on a full pipe while this loop polls it
    outf, errf = tempfile.TemporaryFile("w+"), tempfile.TemporaryFile("w+")
    proc = subprocess.Popen(cmd, stdout=outf, stderr=errf, text=True)
    deadline = start + timeout
    status, usage = 0, None
    while True:
        pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            break
        if time.perf_counter() > deadline:
            proc.kill()
            _, status, usage = os.wait4(proc.pid, 0)
            return {"timeout": True, "wall": time.perf_counter() - start,
                    "peak_gb": usage.ru_maxrss * 1024 / 1e9}  # fmt: skip
        time.sleep(0.05)
    wall = time.perf_counter() - start
    outf.seek(0)
    errf.seek(0)
    out, err = outf.read(), errf.read()
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({code}): {err.strip()}")
    record = json.loads(out.strip().splitlines()[-1])
    return {
        "timeout": False,
        "wall": wall,
        "seconds": float(record["seconds"]),
        "method": record["method"],
        "peak_gb": usage.ru_maxrss * 1024 / 1e9,  # Linux: kilobytes
    }


def method_args(spec: str) -> list[str]:
    """``mcdenoise denoise`` arguments of a ``--methods`` entry ``M[:KEY=VALUE...]``."""
    name, *params = spec.split(":")
    out = ["--method", name]
    for p in params:
        out += ["-p", p]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--layouts", default="full,novar")
    ap.add_argument("--sample", type=Path, default=SAMPLE)
    ap.add_argument("--timeout", type=float, default=600.0)
    ap.add_argument("--keep", type=Path, default=None)
    ap.add_argument("--size", default=f"{WIDTH}x{HEIGHT}", help="WxH (a smaller one to try)")
    ap.add_argument("--methods", default="", help="more methods to run, comma-separated")
    a = ap.parse_args()
    size = tuple(int(v) for v in a.size.lower().split("x"))
    if len(size) != 2 or min(size) < 1:
        raise SystemExit(f"--size {a.size!r}: give WxH, e.g. 3840x2160")
    layouts = [x.strip() for x in a.layouts.split(",") if x.strip()]
    extra_methods = [x.strip() for x in a.methods.split(",") if x.strip()]
    bad = [x for x in layouts if x not in ("full", "novar")]
    if bad:
        raise SystemExit(f"unknown layout(s) {bad}; use full, novar")
    folder = a.keep or Path(tempfile.mkdtemp(prefix="bench4k-"))
    folder.mkdir(parents=True, exist_ok=True)
    print(
        f"{size[0]}x{size[1]} from {a.sample.name}, --threads {a.threads}, "
        f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f} at start"
    )
    header = (
        f"{'layout':<7} {'method':<15} {'wall s':>8} {'method s':>9} {'peak GB':>8} "
        f"{'wall/OIDN':>10} {'s/OIDN':>7} {'meets':>6}"
    )
    print(header)
    for layout in layouts:
        name = f"{size[0]}x{size[1]}_{layout}.exr"
        src = make_input(a.sample, folder / name, layout, size)  # type: ignore[arg-type]
        res = {}
        runs = [("default", []), *[(m, method_args(m)) for m in extra_methods]]
        for label, extra in [*runs, ("oidn", ["--method", "oidn"])]:
            out = folder / f"out_{layout}_{label}.exr"
            args = ["denoise", str(src), "-o", str(out), "--json", "--threads", str(a.threads)]
            res[label] = run(args + extra, a.timeout)
            out.unlink(missing_ok=True)
        base = res["oidn"]
        for label in res:
            r = res[label]
            if r["timeout"]:
                print(
                    f"{layout:<7} {label:<15} > {a.timeout:.0f} s (stopped; peak so far "
                    f"{r['peak_gb']:.2f} GB)"
                )
                continue
            if base["timeout"]:
                ratio_w = ratio_s = float("nan")
            else:
                ratio_w, ratio_s = r["wall"] / base["wall"], r["seconds"] / base["seconds"]
            meets = r["peak_gb"] <= LIMIT_GB and ratio_w <= LIMIT_RATIO
            shown = label if ":" in label else r["method"]
            print(
                f"{layout:<7} {shown:<15} {r['wall']:>8.1f} {r['seconds']:>9.1f} "
                f"{r['peak_gb']:>8.2f} {ratio_w:>10.2f} {ratio_s:>7.2f} "
                f"{('yes' if meets else 'no') if label != 'oidn' else '':>6}"
            )
    print(f"meets: peak <= {LIMIT_GB:g} GB and whole-process wall <= {LIMIT_RATIO:g}x OIDN's")
    print(f"load average {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()

"""Speed and memory of the classical filters, with OIDN's time on the same image as the peer.

Prints, on the current torch thread count:

1. seconds (median of ``--repeats`` runs after one warm-up) at ``--size`` (default 1024×1024)
   with 21×21 windows: per-pixel kernel application (explicit softmax weights), NLM (the
   function's defaults, 7×7 patches, and the 3×3 patches that ``denoise_nlm`` uses), the
   cross-bilateral filter (colour + albedo + normal + depth, per-pixel colour variance), and
   ``pyoidn.denoise(color, albedo, normal, hdr=True)`` on the same image, with each time's
   ratio to OIDN's (skipped with a note when pyoidn is missing);
   Then the whole methods as ``mcdenoise denoise`` runs them (``mcdenoise.denoise.denoise`` on
   a FeatureBuffers with feature variances: sanitising, feature prefiltering, albedo
   demodulation, the filter), which is what a user waits for;
2. peak resident memory of a fresh subprocess per measurement (``VmHWM``, reset once the
   inputs exist; ``ru_maxrss`` where there is no procfs) for a 3840×2160 frame through each
   filter, and the part above the inputs (target: <= 4 GB).

The image is synthetic and seeded (smooth shading × checker albedo, heteroscedastic noise),
so runs are comparable across machines; timings on shared machines are noisy, hence medians
and the ratio to OIDN measured in the same run.

    python benchmarks/bench_filters.py [--size 1024] [--repeats 3] [--no-memory] [--no-timing]
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import json
import math
import resource
import statistics
import subprocess
import sys
import time
from collections.abc import Callable

import torch

from mcdenoise.filters.cross_bilateral import cross_bilateral
from mcdenoise.filters.kernels import Window, accumulate_weighted, apply_kernels
from mcdenoise.filters.nlm import non_local_means

K = 21  # window edge of every filter here (NLM: search radius 10)
TARGETS = {"kernels": 1.0, "nlm": 5.0, "xbf": 8.0}  # seconds at 1024², 2 cores


def make_inputs(h: int, w: int, seed: int = 0) -> dict[str, torch.Tensor]:
    """Seeded synthetic frame, float32 ``(1, C, H, W)``: colour, variance, guides."""
    g = torch.Generator().manual_seed(seed)
    yy = torch.linspace(0, 1, h).view(h, 1).expand(h, w)
    xx = torch.linspace(0, 1, w).view(1, w).expand(h, w)
    checker = ((yy * 24).floor() + (xx * 24).floor()) % 2
    albedo = torch.stack([0.2 + 0.6 * checker, 0.5 - 0.2 * checker, 0.3 + 0.1 * checker])
    shade = 0.3 + 1.5 * xx * (1 - 0.6 * yy)
    clean = albedo * shade
    var = 0.05 * clean.mean(0, keepdim=True)  # brighter -> noisier, as Monte Carlo noise
    color = (clean + var.sqrt() * torch.randn(clean.shape, generator=g)).clamp_min(0)
    nz = 0.6 + 0.4 * (yy > 0.5).float()
    normal = torch.stack([0.5 * (xx > 0.5).float(), (1 - nz**2).clamp_min(0).sqrt(), nz])
    depth = (1 + yy + 0.3 * (xx > 0.7).float()).unsqueeze(0)
    out = {"color": color, "color_var": var, "albedo": albedo, "normal": normal, "depth": depth}
    return {k: v.unsqueeze(0).contiguous() for k, v in out.items()}


def run_filter(name: str, x: dict[str, torch.Tensor]) -> Callable[[], object]:
    """A no-argument callable running filter ``name`` once on inputs ``x``."""
    feats = {"albedo": x["albedo"], "normal": x["normal"], "depth": x["depth"]}
    if name == "kernels":
        # KPCN-like softmax kernels: (1, 441, H, W) weights, built once outside the timing.
        logits = torch.randn(
            1, K * K, *x["color"].shape[2:], generator=torch.Generator().manual_seed(1)
        )
        weights = torch.softmax(logits, dim=1)
        return lambda: apply_kernels(x["color"], weights)
    if name == "kernels-callback":
        c = x["color"]

        def gauss(win: Window) -> torch.Tensor:
            return torch.full_like(win.centre(c[:, :1]), math.exp(-(win.dy**2 + win.dx**2) / 32.0))

        return lambda: accumulate_weighted(c, gauss, K)
    if name == "nlm":
        return lambda: non_local_means(x["color"], color_var=x["color_var"], search_radius=K // 2)
    if name == "nlm-f1":
        return lambda: non_local_means(
            x["color"], color_var=x["color_var"], search_radius=K // 2, patch_radius=1
        )
    if name == "xbf":
        return lambda: cross_bilateral(
            x["color"],
            feats,
            kernel_size=K,
            sigma_spatial=8.0,
            sigma_color=2.0,
            sigma_features={"albedo": 0.1, "normal": 0.3, "depth": 0.02},
            color_var=x["color_var"],
        )
    if name.startswith("method-"):
        from mcdenoise.denoise import denoise
        from mcdenoise.io import FeatureBuffers

        bufs = {k: v[0] for k, v in x.items()}
        for f in ("albedo", "normal", "depth"):  # small feature noise: the prefilter runs
            bufs[f + "_var"] = torch.full_like(bufs[f], 1e-4)
        fb = FeatureBuffers(bufs, spp=16)
        method = name.removeprefix("method-")
        return lambda: denoise(fb, method, device="cpu")
    if name == "oidn":
        import pyoidn

        arrays = [
            x[n][0].permute(1, 2, 0).contiguous().numpy() for n in ("color", "albedo", "normal")
        ]
        return lambda: pyoidn.denoise(*arrays, hdr=True)
    raise SystemExit(f"unknown filter {name!r}")


def timed(fn: Callable[[], object], repeats: int) -> float:
    with torch.no_grad():
        fn()  # warm-up
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _status_bytes(key: str) -> int | None:
    """``VmRSS`` / ``VmHWM`` of this process from ``/proc/self/status`` (Linux), in bytes."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def child(name: str, h: int, w: int) -> None:
    """Subprocess entry: build the inputs, run ``name`` once, print memory figures (bytes).

    The peak is ``VmHWM`` after resetting it once the inputs exist (``/proc/self/clear_refs``):
    ``ru_maxrss`` would also count the parent's memory, inherited through fork + exec.
    """
    x = make_inputs(h, w)
    gc.collect()
    try:  # hand the input construction's freed temporaries back, so they are not reused
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass
    inputs = _status_bytes("VmRSS") or 0
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")  # reset the peak RSS to the current RSS
        exact = True
    except OSError:
        exact = False
    with torch.no_grad():
        run_filter(name, x)()
    peak = _status_bytes("VmHWM") if exact else None
    if peak is None:  # no procfs: ru_maxrss (KiB on Linux, bytes on macOS), an upper bound
        scale = 1 if sys.platform == "darwin" else 1024
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * scale
    print(json.dumps({"inputs": inputs, "peak": peak, "exact": exact}))


def peak_rss(name: str, h: int, w: int) -> dict[str, int]:
    cmd = [sys.executable, __file__, "--_child", name, "--size", f"{w}x{h}"]
    res = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def parse_size(text: str) -> tuple[int, int]:
    """``"1024"`` -> (1024, 1024); ``"3840x2160"`` -> (2160, 3840) as (H, W)."""
    if "x" in text:
        w, h = (int(v) for v in text.split("x"))
        return h, w
    return int(text), int(text)


def timing_table(h: int, w: int, repeats: int) -> None:
    """Median seconds per filter at ``h × w``, and the ratio to OIDN on the same image."""
    x = make_inputs(h, w)
    rows = [
        ("kernels", "apply_kernels, explicit softmax weights (1, 441, H, W)"),
        ("kernels-callback", "accumulate_weighted, Gaussian weight callback"),
        ("nlm", "non_local_means, 7x7 patches (function default)"),
        ("nlm-f1", "non_local_means, 3x3 patches (denoise_nlm default)"),
        ("xbf", "cross_bilateral, colour + albedo + normal + depth"),
        ("method-nlm", "mcdenoise denoise --method nlm, whole pipeline"),
        ("method-cross-bilateral", "mcdenoise denoise --method cross-bilateral, whole pipeline"),
    ]
    try:
        oidn_s: float | None = timed(run_filter("oidn", x), repeats)
    except ImportError:
        oidn_s = None
    print(f"\n{'filter':<24}{'seconds':>9}{'target':>8}{'x OIDN':>9}  what")
    print("-" * 102)
    for name, what in rows:
        s = timed(run_filter(name, x), repeats)
        target = f"{TARGETS[name]:.0f} s" if name in TARGETS and (h, w) == (1024, 1024) else ""
        ratio = f"{s / oidn_s:.1f}" if oidn_s else "-"
        print(f"{name:<24}{s:>9.2f}{target:>8}{ratio:>9}  {what}")
    if oidn_s is None:
        print("note: pyoidn is not installed: no OIDN time, no ratios")
    else:
        what = "pyoidn.denoise(color, albedo, normal, hdr=True)"
        print(f"{'oidn':<24}{oidn_s:>9.2f}{'':>8}{1.0:>9.1f}  {what}")


def memory_table(mh: int, mw: int) -> None:
    """Peak RSS of one subprocess per filter on an ``mh × mw`` frame."""
    print(f"\npeak RSS, {mw}x{mh} frame, one subprocess each (target <= 4 GB through a filter)")
    print(f"{'filter':<24}{'peak GB':>9}{'inputs GB':>11}{'filter GB':>11}")
    print("-" * 55)
    for name in (
        "kernels-callback",
        "nlm",
        "nlm-f1",
        "xbf",
        "method-nlm",
        "method-cross-bilateral",
    ):
        m = peak_rss(name, mh, mw)
        note = "" if m["exact"] else "  (ru_maxrss: upper bound)"
        print(
            f"{name:<24}{m['peak'] / 2**30:>9.2f}{m['inputs'] / 2**30:>11.2f}"
            f"{(m['peak'] - m['inputs']) / 2**30:>11.2f}{note}"
        )
    gb = K * K * mh * mw * 4 / 2**30
    print(f"(apply_kernels is not run at this size: its input weights alone are {gb:.1f} GB)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", default="1024", help="timing size, N or WxH (default 1024)")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs after the warm-up")
    ap.add_argument("--memory-size", default="3840x2160", help="frame for the memory table")
    ap.add_argument("--no-memory", action="store_true", help="skip the memory table")
    ap.add_argument("--no-timing", action="store_true", help="skip the timing table")
    ap.add_argument("--_child", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args._child:
        child(args._child, *parse_size(args.size))
        return 0
    h, w = parse_size(args.size)
    threads = torch.get_num_threads()
    print(f"torch {torch.__version__}, {threads} thread(s); {w}x{h}, {K}x{K} windows")
    if not args.no_timing:
        timing_table(h, w, args.repeats)
    if not args.no_memory:
        memory_table(*parse_size(args.memory_size))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

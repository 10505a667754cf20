"""svgf against per-frame denoisers on a rendered sequence, and svgf's time per 1-megapixel frame.

Quality (``--seq DIR``): DIR is one sequence of ``mcdenoise render --frames N`` (DIR holds
``frame_0000.exr ...`` and ``ref/frame_0000.exr ...``). Every method denoises the part
``--part`` (default spp4) of every frame; per method the table gives the mean per-frame
relMSE (all frames, and frames t >= 4, after svgf's spatial-variance warm-up), the temporal
relMSE of issue 23 (mean over t >= 1 of relMSE of ``o_t − o_{t−1}`` against
``r_t − r_{t−1}``, normalised by ``r_t² + 0.01``: :func:`mcdenoise.eval.temporal_relmse`),
Noisebase's tPSNR, and the mean seconds per frame.

Time (``--time-size N``): the frames of ``--seq`` tiled to N×N (the same buffers, motion and
masks repeated), svgf over ``--time-frames`` frames with ``--threads`` torch threads (median
seconds of the frames after the warm-up, and frame 0 apart), and OIDN on the same frame in the
same run (median of 3), so the ratio holds on a loaded machine.

Example (the numbers of docs/results/temporal.md)::

    .venv/bin/python benchmarks/bench_svgf.py --make-spec /tmp/cornell_anim.toml
    .venv/bin/mcdenoise render /tmp/cornell_anim.toml --frames 8 --res 128 --spp 4 \\
        --ref-spp 1024 --threads 1 -o /tmp/seq
    .venv/bin/python benchmarks/bench_svgf.py --seq /tmp/seq/cornell_anim \\
        --methods "svgf,svgf:phi_color=10;use_color_var=0,nlm,oidn"
    .venv/bin/python benchmarks/bench_svgf.py --seq /tmp/seq/cornell_anim --skip-quality \\
        --time-size 1024 --threads 2
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import torch

from mcdenoise.denoise import denoise_sequence
from mcdenoise.eval import temporal_relmse
from mcdenoise.eval.metrics import relmse
from mcdenoise.eval.temporal_metrics import tpsnr
from mcdenoise.io import load_buffers
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.registry import get_method
from mcdenoise.threads import apply_threads

WARMUP = 4  # svgf's spatial variance estimate runs while the history holds < 4 frames


def _frames(seq: Path, part: str) -> tuple[list[FeatureBuffers], list[torch.Tensor]]:
    files = sorted(seq.glob("frame_*.exr"))
    if not files:
        sys.exit(f"no frame_*.exr in {seq}")
    frames = [load_buffers(f, part=part) for f in files]
    refs = [load_buffers(seq / "ref" / f.name).color for f in files]
    return frames, refs


def quality(seq: Path, part: str, methods: list[str]) -> None:
    frames, refs = _frames(seq, part)
    h, w = frames[0].shape
    print(
        f"sequence {seq} ({len(frames)} frames, {w}x{h}, part {part}); "
        f"motion_valid mean {float(torch.stack([f['motion_valid'].mean() for f in frames[1:]]).mean()):.3f}"
    )
    print()
    print(
        "| method | relMSE (all frames) | relMSE (t >= 4) | temporal relMSE | tPSNR (dB) | s/frame |"
    )
    print("|---|---|---|---|---|---|")
    rows: dict[str, list[torch.Tensor]] = {"noisy": [f.color for f in frames]}
    secs: dict[str, float] = {"noisy": 0.0}
    for spec in methods:
        m, _, extra = spec.partition(":")  # e.g. svgf:phi_color=10;use_color_var=0
        params = dict(kv.split("=", 1) for kv in extra.split(";") if kv) or None
        if get_method(m).unavailable():
            print(f"| {m} | unavailable: {get_method(m).unavailable()} | | | | |")
            continue
        results = list(denoise_sequence(iter(frames), m, params=params))
        rows[spec] = [r.image for r in results]
        secs[spec] = statistics.fmean(r.seconds for r in results)
    for name, outs in rows.items():
        per = [relmse(o.numpy(), r.numpy()) for o, r in zip(outs, refs)]
        late = per[WARMUP:] or per
        t = temporal_relmse([o.numpy() for o in outs], [r.numpy() for r in refs])
        tp = tpsnr([o.numpy() for o in outs], [r.numpy() for r in refs])
        print(
            f"| {name} | {statistics.fmean(per):.5f} | {statistics.fmean(late):.5f} | {t:.5f} "
            f"| {tp:.2f} | {secs[name]:.3f} |"
        )
    print()
    print("per-frame relMSE:")
    for name, outs in rows.items():
        per = [relmse(o.numpy(), r.numpy()) for o, r in zip(outs, refs)]
        print(f"  {name:8s} " + " ".join(f"{v:.4f}" for v in per))


def timing(seq: Path, part: str, size: int, n_frames: int, threads: int) -> None:
    apply_threads(threads)
    frames, _ = _frames(seq, part)
    big = [frames[i % len(frames)].tiled(size, size) for i in range(n_frames)]
    load = os.getloadavg()[0]
    secs, cpu = [], []
    results = denoise_sequence(iter(big), "svgf")
    while True:  # wall seconds of the method (denoise_sequence's) and CPU seconds of the process
        c0 = time.process_time()
        r = next(results, None)
        if r is None:
            break
        cpu.append(time.process_time() - c0)
        secs.append(r.seconds)
    steady = secs[WARMUP:] or secs
    steady_cpu = cpu[WARMUP:] or cpu
    oidn = get_method("oidn")
    line = ""
    if oidn.unavailable() is None:
        o, oc = [], []
        for _ in range(3):
            c0 = time.process_time()
            o.append(next(denoise_sequence([big[0]], "oidn")).seconds)
            oc.append(time.process_time() - c0)
        ratio = statistics.median(steady) / statistics.median(o)
        line = (
            f"; OIDN (same frame, same run): median {statistics.median(o):.3f} s "
            f"(CPU {statistics.median(oc):.2f} s); svgf/OIDN {ratio:.2f}"
        )
    print(
        f"svgf {size}x{size}, {threads} thread(s), load average {load:.1f} at start: "
        f"frame 0 {secs[0]:.3f} s, frames >= {WARMUP} median {statistics.median(steady):.3f} s "
        f"(all: {' '.join(f'{s:.2f}' for s in secs)}){line}; CPU seconds of the process per "
        f"frame (all threads, includes reading nothing: frames are in memory) frames >= {WARMUP} "
        f"median {statistics.median(steady_cpu):.2f}, frame 0 {cpu[0]:.2f}"
    )


def make_spec(out: Path) -> None:
    """Write the measured scene: ``data/scenes/cornell.toml`` with an 8° orbit over the
    sequence and the short block moving 0.3 to the left (world x) from first to last frame."""
    src = (Path(__file__).resolve().parents[1] / "data/scenes/cornell.toml").read_text()
    block = (
        "transform = { translate = [0.4, 0.3, 0.3], rotate = [0, -18, 0], "
        "scale = [0.3, 0.3, 0.3] }\n"
    )
    if block not in src or "[render]\n" not in src:
        sys.exit("data/scenes/cornell.toml changed: update make_spec")
    text = src.replace('name = "cornell"', 'name = "cornell_anim"', 1)
    anim = '[animation]\ncamera_path = "orbit"\nangle = 8\n\n[render]\n'
    text = text.replace("[render]\n", anim, 1)
    text = text.replace(block, block + "motion = { translate = [-0.3, 0, 0] }\n", 1)
    out.write_text(text)
    print(f"wrote {out}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seq", type=Path, help="one sequence folder of mcdenoise render --frames")
    ap.add_argument("--make-spec", type=Path, help="write the measured scene spec here and stop")
    ap.add_argument("--part", default="spp4")
    ap.add_argument(
        "--methods",
        default="svgf,nlm,oidn",
        help="comma-separated; METHOD:key=value;key=value sets parameters",
    )
    ap.add_argument("--threads", type=int, default=1, help="torch threads (quality and time)")
    ap.add_argument("--time-size", type=int, default=0, help="also time svgf on N x N frames")
    ap.add_argument("--time-frames", type=int, default=8)
    ap.add_argument("--skip-quality", action="store_true")
    a = ap.parse_args()
    if a.make_spec:
        make_spec(a.make_spec)
        return
    if a.seq is None:
        ap.error("--seq is required")
    apply_threads(a.threads)
    if not a.skip_quality:
        quality(a.seq, a.part, [m.strip() for m in a.methods.split(",") if m.strip()])
    if a.time_size:
        timing(a.seq, a.part, a.time_size, a.time_frames, a.threads)


if __name__ == "__main__":
    main()

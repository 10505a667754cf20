"""Matching outputs to references in ``mcdenoise eval --ref DIR DIR`` (issue 33, item 7):
linear in the number of files.

``python benchmarks/bench_eval_matching.py [--sizes 100,300,1000,3000] [--cli 300]``
    Per N and layout, writes N references ``ref/s00000.exr`` ... and N outputs
    ``out/s00000_spp4_nlm.exr`` (4×4 EXRs) into a temporary folder: ``plain`` outputs record
    nothing (matched by name; one header read per output); ``recorded`` outputs are as
    ``mcdenoise denoise`` writes them, their header naming a noisy input
    ``in/s00000_spp4.exr`` (``mcdenoise:source``) and every file its scene
    (``mcdenoise:scene``), so ``eval`` also reads the reference's and the noisy input's
    headers (three per pair). It prints the seconds of

    * ``plan``: :func:`mcdenoise.eval.evaluate.plan_files`, everything ``eval`` does before
      it reads pixels: scanning the folders, a stat per file (is an output a reference?),
      the headers, matching names (each header read takes ~0.15-0.25 ms here, so the
      recorded layout's 9000 reads at N = 3000 are most of its time);
    * ``names``: the name matching alone, N output stems against N reference stems, with
      :class:`~mcdenoise.eval.evaluate.PrefixMatcher` (``new``) and with the loop over every
      candidate it replaced (``old``), and their ratio (the peer in the same run).

    ``--cli N`` also times the whole ``mcdenoise eval --ref REF OUT --metrics relmse`` on N
    pairs in a subprocess (metrics, preview images and the report included; FLIP is left out
    because flip_evaluator costs ~70 ms per image even at 4×4).

The issue's target: 3000 pairs matched in under 2 s (before: 100/300/600 files took
4.8/9.6/23 s through the CLI and 3000 did not finish in 60 s).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _write_tiny(path: Path, attributes: dict[str, str]) -> None:
    """A 4×4 RGB float EXR with ``attributes``, written directly (no fsync: setup speed)."""
    import numpy as np
    import OpenImageIO as oiio

    spec = oiio.ImageSpec(4, 4, 3, "float")
    spec.channelnames = ("R", "G", "B")
    for k, v in attributes.items():
        spec.attribute(k, v)
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), spec):
        raise RuntimeError(f"cannot write {path}")
    out.write_image(np.full((4, 4, 3), 0.5, np.float32))
    out.close()


def make_set(root: Path, n: int, recorded: bool) -> tuple[Path, Path]:
    """``(ref folder, output folder)`` of ``n`` scenes under ``root`` (see the docstring)."""
    ref, noisy, out = root / "ref", root / "in", root / "out"
    for d in (ref, noisy, out):
        d.mkdir(parents=True)
    for i in range(n):
        scene = f"s{i:05d}"
        if not recorded:
            _write_tiny(ref / f"{scene}.exr", {})
            _write_tiny(out / f"{scene}_spp4_nlm.exr", {})
            continue
        _write_tiny(ref / f"{scene}.exr", {"mcdenoise:scene": scene})
        src = noisy / f"{scene}_spp4.exr"
        _write_tiny(src, {"mcdenoise:scene": scene, "mcdenoise:spp": "4"})
        _write_tiny(
            out / f"{scene}_spp4_nlm.exr",
            {"mcdenoise:method": "nlm", "mcdenoise:source": str(src), "mcdenoise:scene": scene},
        )
    return ref, out


def _old_match(stem: str, candidates: list[str]) -> str | None:
    """The matching loop ``match_prefix`` had: every candidate, for every stem."""
    best: str | None = None
    for cand in candidates:
        if not cand or not stem.startswith(cand):
            continue
        if len(stem) > len(cand) and stem[len(cand)].isalnum():
            continue
        if best is None or len(cand) > len(best):
            best = cand
    return best


def bench(n: int, recorded: bool, cli: bool) -> None:
    from mcdenoise.eval.evaluate import plan_files
    from mcdenoise.eval.matching import PrefixMatcher

    with tempfile.TemporaryDirectory() as tmp:
        ref, out = make_set(Path(tmp), n, recorded)
        t0 = time.perf_counter()
        plan = plan_files(ref, [out])
        plan_s = time.perf_counter() - t0
        assert len(plan.planned) == n and len(plan.noisy_files) == (n if recorded else 0)

        stems = [p.stem for p in sorted(out.iterdir())]
        refs = [p.stem for p in sorted(ref.iterdir())]
        t0 = time.perf_counter()
        match = PrefixMatcher(refs)
        new = [match(s) for s in stems]
        new_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        old = [_old_match(s, refs) for s in stems]
        old_s = time.perf_counter() - t0
        assert new == old
        line = (
            f"{'recorded' if recorded else 'plain':8s} {n:5d} pairs  plan {plan_s:6.3f} s  "
            f"names: new {new_s * 1e3:6.2f} ms, "
            f"old {old_s * 1e3:9.1f} ms, old/new {old_s / max(new_s, 1e-9):7.0f}x"
        )
        if cli:
            cmd = [sys.executable, "-m", "mcdenoise_cli.main", "eval", "--ref", str(ref)]
            cmd += [str(out), "--metrics", "relmse", "--no-progress", "-o", str(Path(tmp) / "r")]
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, cwd=ROOT)
            line += f"  cli {time.perf_counter() - t0:7.2f} s"
        print(line, flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="100,300,1000,3000", help="comma-separated pair counts")
    ap.add_argument("--cli", type=int, default=0, metavar="N", help="also time the CLI up to N")
    args = ap.parse_args()
    for recorded in (False, True):
        for n in (int(s) for s in args.sizes.split(",")):
            bench(n, recorded, cli=0 < n <= args.cli)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Where the default method's time goes (issue 38): a stage table at 1 MP and 4K, and the
start-up of ``mcdenoise denoise``.

Stages of ``kpcn`` (the default for a file with colour, albedo and normal), each timed on its
own (median of ``--repeat`` runs after a warm-up, ``--threads`` torch threads):

* ``read``: :func:`mcdenoise.io.load_buffers` of the input EXR;
* ``prepare``: :func:`mcdenoise.prep.kpcn.prepare_tensors` (sanitising, the guide prefilter,
  the encoders' normalisation inputs);
* ``  of which prefilter``: the adaptive guide prefilter alone
  (:func:`mcdenoise.prep.kpcn.prepare_tensors` with ``prefilter=off`` subtracted);
* ``features``: the source encoder and U-Net trunk (:meth:`KpcnModel.features`), in the
  precision the method picks (``--precision``, default ``auto``: bfloat16 on a CPU that has it);
* ``kernels``: kernel prediction, softmax and application at every scale and the compositor
  (:meth:`KpcnModel.reconstruct`);
* ``model (tiled)``: :meth:`KpcnModel.denoise_tensors`, the whole network as the method runs
  it (tiles with halos), so the overhead of tiling shows against ``features + kernels``;
* ``write``: :func:`mcdenoise.io.save_buffers` of the output.

OIDN (``pyoidn``, in-process, albedo and normal, same threads) on the same frame is printed
beside it when installed.

Start-up: the wall time of ``mcdenoise --version`` and of ``python -c "import
mcdenoise.denoise"`` in fresh processes (median of 3), and the largest imports a ``kpcn``
denoise makes (``python -X importtime``, cumulative, two levels deep). The whole process
against the method's own seconds: ``benchmarks/bench_4k.py --size 1024x1024``.

Inputs are tiled from a 128² sample (``data/samples/cornell_spp4.exr``: every buffer with its
variance; ``--layout novar`` drops the variances, as a plain Mitsuba or Cycles file has them).

    python benchmarks/bench_profile.py [--sizes 1024x1024,3840x2160] [--threads 2]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

import torch

from mcdenoise.io import load_buffers, save_buffers
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.models.precision import PRECISIONS, resolve_precision
from mcdenoise.models.weights import load_kpcn, shipped_model_path
from mcdenoise.prep.kpcn import DEFAULT_PREFILTER, prepare_tensors, source_for
from mcdenoise.threads import apply_threads

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "data" / "samples" / "cornell_spp4.exr"


def _median(fn: Callable[[], object], repeat: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _input(size: tuple[int, int], layout: str) -> FeatureBuffers:
    b = load_buffers(SAMPLE)
    if layout == "novar":
        b = b.subset([n for n in b.names() if not n.endswith("_var")])
    return b.tiled(*size)


def _oidn(b: FeatureBuffers, repeat: int) -> float | None:
    try:
        from mcdenoise.registry import get_method

        method = get_method("oidn")
        if method.check_input and method.check_input(b, dict(method.defaults)):
            return None
    except Exception:  # not installed here
        return None
    run = method.run
    assert run is not None
    params = dict(method.defaults)
    return _median(lambda: run(b, params, torch.device("cpu")), repeat)


def profile(size: tuple[int, int], layout: str, repeat: int, tmp: Path, precision: str) -> None:
    b = _input(size, layout)
    precision = resolve_precision(precision, "cpu")
    path = tmp / f"in_{size[0]}x{size[1]}.exr"
    save_buffers(path, b)
    model = load_kpcn(shipped_model_path("kpcn"))
    src = source_for(b, model.card.sources)
    rows: list[tuple[str, float]] = []
    rows.append(("read", _median(lambda: load_buffers(path), repeat)))
    prep = _median(lambda: prepare_tensors(b, src, DEFAULT_PREFILTER), repeat)
    raw = _median(lambda: prepare_tensors(b, src, "off"), repeat)
    rows += [("prepare", prep), ("  of which prefilter", prep - raw)]
    t = {k: v[None] for k, v in prepare_tensors(b, src, DEFAULT_PREFILTER).items()}
    m = model.multiple
    h, w = (size[1] // m) * m, (size[0] // m) * m
    tc = {k: v[..., :h, :w].contiguous() for k, v in t.items()}
    from mcdenoise.filters.albedo import demodulate

    with torch.no_grad():
        rows.append(("features", _median(lambda: model.features(tc, src, precision), repeat)))
        feats = model.features(tc, src, precision)
        irr, _ = demodulate(tc["color"], tc.get("albedo"))
        rows.append(("kernels", _median(lambda: model.reconstruct(irr, feats), repeat)))
        feats = []
        tiled = partial(model.denoise_tensors, t, src, precision=precision)
        rows.append(("model (tiled)", _median(tiled, repeat)))
        out = tiled()[0]
    res = FeatureBuffers({"color": out})
    rows.append(("write", _median(lambda: save_buffers(tmp / "out.exr", res), repeat)))
    total = sum(v for k, v in rows if k in ("read", "prepare", "model (tiled)", "write"))
    mp = size[0] * size[1] / 1e6
    print(
        f"\nkpcn, {size[0]}x{size[1]} ({mp:.2f} MP, layout {layout}, source {src}, "
        f"trunk {precision})"
    )
    for name, sec in rows:
        print(f"  {name:22s} {sec:8.3f} s  {100 * sec / total:5.1f} %")
    print(f"  {'sum (read..write)':22s} {total:8.3f} s")
    o = _oidn(b, repeat)
    if o is not None:
        print(f"  {'oidn (same frame)':22s} {o:8.3f} s  model/oidn {rows[-2][1] / o:.2f}")


def _wall(cmd: list[str]) -> float:
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def startup(top: int) -> None:
    exe = [sys.executable, "-m", "cli.main"] if not _console() else [_console()]
    print("\nstart-up (median of 3 fresh processes):")
    print(f"  mcdenoise --version        {_wall([*exe, '--version']):.3f} s")
    print(
        f"  import mcdenoise.denoise    "
        f"{_wall([sys.executable, '-c', 'import mcdenoise.denoise']):.3f} s"
    )
    print(f"  python -c pass             {_wall([sys.executable, '-c', 'pass']):.3f} s")
    code = "import mcdenoise.denoise, mcdenoise.output; from mcdenoise.registry import get_method; get_method('kpcn')"
    r = subprocess.run(
        [sys.executable, "-X", "importtime", "-c", code],
        capture_output=True,
        text=True,
        cwd=ROOT,
        check=True,
    )
    rows = []
    for line in r.stderr.splitlines():
        if not line.startswith("import time:") or line.count("|") != 2:
            continue
        _, cum, name = line.split("|")
        if not cum.strip().isdigit():
            continue
        depth = (len(name) - len(name.lstrip())) // 2
        if depth <= 2:  # top-level imports and what they import directly
            rows.append((int(cum), name.strip()))
    print(f"  the largest imports of a kpcn denoise (cumulative, two levels, of {len(rows)}):")
    for cum, name in sorted(rows, reverse=True)[:top]:
        print(f"    {cum / 1e6:7.3f} s  {name}")


def _console() -> str:
    exe = Path(sys.executable).with_name("mcdenoise")
    return str(exe) if exe.is_file() else ""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="1024x1024,3840x2160")
    ap.add_argument("--layout", choices=("full", "novar"), default="novar")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--top", type=int, default=12)
    ap.add_argument("--no-startup", action="store_true")
    ap.add_argument(
        "--precision", choices=PRECISIONS, default="auto", help="the trunk's, as -p precision"
    )
    args = ap.parse_args()
    apply_threads(args.threads)
    os.environ.setdefault("OIDN_NUM_THREADS", str(args.threads))
    print(f"load average {os.getloadavg()[0]:.1f}, {args.threads} threads")
    with tempfile.TemporaryDirectory() as tmp:
        for s in args.sizes.split(","):
            w, h = (int(x) for x in s.lower().split("x"))
            profile((w, h), args.layout, args.repeat, Path(tmp), args.precision)
    if not args.no_startup:
        startup(args.top)


if __name__ == "__main__":
    main()

"""Issues 23 and 37's numbers on held-out sequences: kpcn-temporal (offline window and causal
recurrent mode) against per-frame kpcn and OIDN, svgf against per-frame nlm, ghosting, and
the time per frame at a megapixel.

Data (``--data DIR``): a folder of sequences of ``mcdenoise render --frames N``
(``DIR/<id>/frame_XXXX.exr`` and ``DIR/<id>/ref/frame_XXXX.exr``), none of whose specs or
seeds the temporal model was trained on (checked against the sequence names in its model
card). Every method denoises the part ``--part`` (default ``spp4``) of every frame, in order
(temporal methods keep their history; per-frame ones run frame by frame).

Per sequence and method (``mcdenoise.eval``'s definitions):

* per-frame relMSE: the mean over the frames of ``mean((o − r)² / (r² + 0.01))``;
* temporal relMSE: :func:`mcdenoise.eval.temporal_relmse` (mean over ``t ≥ 1`` of the relMSE
  of ``o_t − o_{t−1}`` against ``r_t − r_{t−1}``, normalised by ``r_t² + 0.01``);
* ghosting: the relMSE over the pixels of frames ``t ≥ 1`` whose ``motion_valid`` is 0
  (disocclusions, object edges: where a temporal method must not use its history), pooled
  over those pixels of the sequence;
* seconds per frame (``denoise_sequence``'s wall time, loaded machine).

The table gives geometric means over the sequences, then the issue's targets as ratios.
``--time-size N`` adds svgf's time on the first sequence's frames tiled to N×N (median of the
frames after its 4-frame warm-up) with OIDN on the same frame in the same run (median of 3).
``--time-kpcn N`` times kpcn-temporal (its default window), its causal mode and kpcn on 6
frames tiled to N×N in the same run (median seconds per frame over frames 3–5, once every
window is full).

Methods are ``name[:param=value;...]``, e.g. ``kpcn-temporal:mode=causal`` (the shipped
recurrent causal model) or ``kpcn-temporal:model=runs/x``. Every kpcn-temporal model named is
checked: none may have been trained or validated on a held-out sequence.

``--drop-motion-valid`` gives the methods the frames without the renderer's masks (as Blender
Cycles files come): what their own disocclusion tests are worth.

Example (the numbers of docs/results/temporal.md)::

    .venv/bin/python benchmarks/bench_temporal.py --data data/generated/seq-heldout --threads 1
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time
from pathlib import Path

import torch

from mcdenoise.denoise import denoise_sequence
from mcdenoise.eval import temporal_relmse
from mcdenoise.io import load_buffers
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.method import Method
from mcdenoise.modelfile import read_card
from mcdenoise.models.weights import shipped_model_path
from mcdenoise.registry import get_method
from mcdenoise.threads import apply_threads

DEFAULT_METHODS = "kpcn-temporal,kpcn-temporal:mode=causal,kpcn,oidn,svgf,nlm"
KT = "kpcn-temporal"
CAUSAL = "kpcn-temporal:mode=causal"


def _method(name: str) -> Method:
    try:
        return get_method(name)
    except Exception:  # not registered in this checkout: the module's own METHOD
        if name == KT:
            from mcdenoise.methods.kpcn_temporal import METHOD

            return METHOD
        raise


def _parse(spec: str) -> tuple[str, dict[str, str]]:
    name, _, rest = spec.partition(":")
    params = dict(p.split("=", 1) for p in rest.split(";") if p)
    return name, params


def _sequences(data: Path) -> list[Path]:
    seqs = sorted(d for d in data.iterdir() if d.is_dir() and any(d.glob("frame_*.exr")))
    if not seqs:
        sys.exit(f"{data}: no sequence folders (<id>/frame_*.exr)")
    return seqs


def _load(seq: Path, part: str) -> tuple[list[FeatureBuffers], list[torch.Tensor]]:
    files = sorted(seq.glob("frame_*.exr"))
    return [load_buffers(f, part=part) for f in files], [
        load_buffers(seq / "ref" / f.name).color for f in files
    ]


def _relmse_map(o: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    o, r = o.double(), r.double()
    return (o - r) ** 2 / (r**2 + 0.01)


def _scores(frames, outs, refs) -> dict[str, float]:
    rel = [float(_relmse_map(o, r).mean()) for o, r in zip(outs, refs)]
    err, count = 0.0, 0
    for t in range(1, len(outs)):
        valid = frames[t].get("motion_valid")
        if valid is None:
            continue
        m = valid[0] <= 0.5
        err += float(_relmse_map(outs[t], refs[t]).sum(0)[m].sum())
        count += 3 * int(m.sum())
    return {
        "rel": sum(rel) / len(rel),
        "trel": temporal_relmse([o.numpy() for o in outs], [r.numpy() for r in refs]),
        "ghost": err / count if count else math.nan,
    }


def _gm(values: list[float]) -> float:
    v = [x for x in values if math.isfinite(x) and x > 0]
    return math.exp(sum(math.log(x) for x in v) / len(v)) if v else math.nan


def timing(seq: Path, part: str, size: int) -> None:
    frames, _ = _load(seq, part)
    big = [frames[i % len(frames)].tiled(size, size) for i in range(7)]
    load = os.getloadavg()[0]
    secs = [r.seconds for r in denoise_sequence(iter(big), "svgf")]
    steady = statistics.median(secs[4:])
    o = [next(denoise_sequence([big[0]], "oidn")).seconds for _ in range(3)]
    mp = size * size / 1e6
    print(
        f"\nsvgf time, {size}x{size} ({mp:.2f} MP), load average {load:.1f}: "
        f"{steady:.3f} s per frame (frames >= 4), {steady / mp:.3f} s/MP; OIDN same frame "
        f"{statistics.median(o):.3f} s ({statistics.median(o) / mp:.3f} s/MP); "
        f"svgf/OIDN {steady / statistics.median(o):.2f}; target <= 0.5 s/MP on 2 cores"
    )


def timing_kpcn(seq: Path, part: str, size: int, temporal_model: str) -> None:
    frames, _ = _load(seq, part)
    big = [frames[i % len(frames)].tiled(size, size) for i in range(6)]
    load = os.getloadavg()[0]
    res = {}
    for spec in (KT, CAUSAL, "kpcn"):
        name, params = _parse(spec)
        if name == KT and temporal_model and "mode" not in params:
            params["model"] = temporal_model
        secs = [r.seconds for r in denoise_sequence(iter(big), _method(name), params=params)]
        res[spec] = statistics.median(secs[3:])
    mp = size * size / 1e6
    print(f"\nseconds per frame, {size}x{size} ({mp:.2f} MP), load average {load:.1f}:")
    for spec, sec in res.items():
        print(f"  {spec:28s} {sec:7.2f} s  ({sec / res['kpcn']:.2f}x kpcn)")


def _trained_on(model: str) -> set[str]:
    training = read_card(model).get("training", {})
    return set(training.get("train_sequences", [])) | set(training.get("val_sequences", []))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--part", default="spp4")
    ap.add_argument("--methods", default=DEFAULT_METHODS)
    ap.add_argument("--temporal-model", default="", help="kpcn-temporal model (default: shipped)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--time-size", type=int, default=0)
    ap.add_argument("--time-kpcn", type=int, default=0, metavar="N")
    ap.add_argument("--per-sequence", action="store_true")
    ap.add_argument(
        "--drop-motion-valid",
        action="store_true",
        help="the methods get the frames without motion_valid / motion_next_valid (as Blender "
        "Cycles writes them); ghosting is still scored on the renderer's mask",
    )
    args = ap.parse_args()
    apply_threads(args.threads)
    seqs = _sequences(args.data)
    specs = [s.strip() for s in args.methods.split(",") if s.strip()]
    models = {args.temporal_model or str(shipped_model_path(KT))}
    for spec in specs:
        name, params = _parse(spec)
        if name == KT and "model" in params:
            models.add(params["model"])
        elif name == KT and params.get("mode") == "causal":
            causal = shipped_model_path(KT, "causal")
            models.add(str(causal if causal.is_file() else shipped_model_path(KT)))
    for model in sorted(models):
        shared = sorted(_trained_on(model) & {s.name for s in seqs})
        if shared:
            sys.exit(f"{model}: trained on held-out sequences {', '.join(shared)}")
    scores: dict[str, list[dict[str, float]]] = {s: [] for s in specs}
    seconds: dict[str, list[float]] = {s: [] for s in specs}
    t0 = time.time()
    used = []
    for seq in seqs:
        frames, refs = _load(seq, args.part)
        if "albedo" not in frames[0]:  # an AO render: kpcn, kpcn-temporal and OIDN need albedo
            print(f"{seq.name}: skipped (no albedo: an AO render)", flush=True)
            continue
        used.append(seq)
        for spec in specs:
            name, params = _parse(spec)
            if name == KT and args.temporal_model and "mode" not in params:
                params.setdefault("model", args.temporal_model)
            inputs = frames
            if args.drop_motion_valid:
                keep = [
                    n for n in frames[0].names() if n not in ("motion_valid", "motion_next_valid")
                ]
                inputs = [f.subset(keep) for f in frames]
            res = list(denoise_sequence(iter(inputs), _method(name), params=params, device="cpu"))
            sc = _scores(frames, [r.image for r in res], refs)
            scores[spec].append(sc)
            seconds[spec].append(sum(r.seconds for r in res) / len(res))
            if args.per_sequence:
                print(
                    f"{seq.name:22s} {spec:34s} relMSE {sc['rel']:.5f} temporal "
                    f"{sc['trel']:.5f} ghost {sc['ghost']:.5f}",
                    flush=True,
                )
    print(
        f"\n{len(used)} held-out sequences of {args.data} ({args.part}), geometric means; "
        f"{time.time() - t0:.0f} s, load average {os.getloadavg()[0]:.1f}\n"
    )
    print(f"{'method':36s} {'relMSE':>9s} {'temporal':>9s} {'ghosting':>9s} {'s/frame':>8s}")
    gm = {}
    for spec in specs:
        gm[spec] = {k: _gm([s[k] for s in scores[spec]]) for k in ("rel", "trel", "ghost")}
        g = gm[spec]
        print(
            f"{spec:36s} {g['rel']:9.5f} {g['trel']:9.5f} {g['ghost']:9.5f} "
            f"{statistics.mean(seconds[spec]):8.3f}"
        )

    def ratio(a: str, b: str, key: str, target: float, below: bool = True) -> None:
        if a in gm and b in gm:
            r = gm[a][key] / gm[b][key]
            ok = r <= target if below else r < target
            print(
                f"  {a} / {b} {key}: {r:.3f} (target {'<=' if below else '<'} {target}): "
                f"{'met' if ok else 'NOT met'}"
            )

    print("\nissue 37 targets:")
    ratio(KT, "kpcn", "trel", 0.6)
    ratio(KT, "oidn", "trel", 0.6)
    ratio(KT, "kpcn", "rel", 0.9)
    ratio(CAUSAL, "kpcn", "trel", 0.75)
    ratio(CAUSAL, "kpcn", "rel", 1.0)
    ratio("svgf", "nlm", "trel", 1.0, below=False)
    ratio(KT, "kpcn", "ghost", 1.2)
    for spec in (KT, CAUSAL):
        if spec in scores and "kpcn" in scores:
            worse = [
                f"{seq.name} ({key})"
                for seq, a, b in zip(used, scores[spec], scores["kpcn"])
                for key in ("rel", "trel")
                if a[key] > b[key]
            ]
            print(
                f"  {spec}: sequences worse than kpcn (target: none): "
                f"{len(worse)}{': ' + ', '.join(worse) if worse else ''}"
            )
    if args.time_size:
        timing(used[0], args.part, args.time_size)
    if args.time_kpcn:
        timing_kpcn(used[0], args.part, args.time_kpcn, args.temporal_model)


if __name__ == "__main__":
    main()

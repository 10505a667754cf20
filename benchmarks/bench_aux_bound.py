"""How much a better auxiliary prefilter could give ``kpcn`` on the out-of-distribution set.

Issue 34, item 1, first measurement ("measure the bound first"): ``kpcn`` (shipped weights,
unchanged) on the images of ``benchmarks/bench_ood.py`` with its auxiliary buffers replaced,
each variant's relMSE divided by OIDN's on the same file (OIDN run as ``bench_ood`` runs it:
pyoidn, HDR, the file's own noisy albedo and normal, OIDN's internal prefilter). Variants:

``shipped``
    ``kpcn`` as shipped (default ``prefilter``: ``adaptive``).
``off``
    ``prefilter=off``: the noisy auxiliaries as the renderer wrote them.
``ref``
    the bound: albedo, normal, depth and position (and their variance buffers) taken from the
    canonical reference ``r256/ref/<id>.exr`` (2048 spp), ``prefilter=off`` (they are clean).
``ref-albedo`` / ``ref-normal``
    only that one buffer (and its variance) from the reference; the others as shipped
    (``adaptive``: a variance buffer near zero leaves the clean one as it is). A scene whose
    reference has no such buffer (the AO scene has no albedo) is skipped.
``oidn-aux``
    albedo and normal prefiltered by OIDN's own networks (the ``RT`` filter with only the
    ``albedo``, resp. ``normal``, image set and an ``output``: OIDN's documented way of
    prefiltering auxiliary images; ``quality=high``, 1 thread) with a zero variance buffer
    each (so the shipped ``adaptive`` prefilter leaves them as they are, to 1e-6, and the
    ``full`` source's inputs call them clean), depth and position prefiltered as shipped (OIDN
    has no filter for them; the plain ``aov`` files' ``basic`` source does not use them). A
    diagnostic only: the shipped method must not need OIDN. OIDN takes albedo
    in [0, 1], but Mitsuba's albedo of glossy lobes exceeds 1 (up to 437 on
    ``metals_rough``; 1.5-3.4 % of the pixels of the metal, neon, city and depth-of-field
    scenes), and ``kpcn`` demodulates by it as it is: the part above 1 is added back to OIDN's
    output unfiltered.
``oidn-aux-clamp``
    the same with OIDN's output as it is (albedo clamped to [0, 1], as OIDN itself sees it).

Also recorded per image: the mean squared error of the noisy and the OIDN-filtered albedo and
normal against the reference's, and the seconds of each OIDN auxiliary filter and of each
``kpcn`` run (what a learned prefilter must beat). Loading, the OIDN and shipped ``kpcn``
rows, the sound-baseline rule and the metrics are ``bench_ood``'s.

    python benchmarks/bench_aux_bound.py [--data data/generated/ood] [--sets aov256,r256]
        [--levels 4,16,64] [--variants shipped,off,ref,ref-albedo,ref-normal,oidn-aux]
        [--scenes a,b] [--json OUT] [--markdown OUT] [--from-json RUN.json]
    python benchmarks/bench_aux_bound.py --speed 3 --scenes dof_extreme --levels 4
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

# bench_ood sets OMP_NUM_THREADS / OIDN_NUM_THREADS = 1 before torch and pyoidn are imported
import bench_ood  # isort: skip  (benchmarks/ is sys.path[0] when run as a script)
import numpy as np
import torch

from mcdenoise.denoise import denoise
from mcdenoise.errors import McdenoiseError
from mcdenoise.eval.metrics import relmse, ssim
from mcdenoise.geomean import geometric_mean
from mcdenoise.io import load_buffers
from mcdenoise.io.atomic import write_text_atomic
from mcdenoise.io.buffers import FeatureBuffers

BASELINE = bench_ood.BASELINE
SHIPPED = "kpcn"  # bench_ood's row of the shipped kpcn
REF_FEATURES = ("albedo", "normal", "depth", "position")
OIDN_AUX = ("albedo", "normal")
#: Variant name -> what it is (docstring above).
VARIANTS = {
    "shipped": "kpcn as shipped (prefilter=adaptive)",
    "off": "prefilter=off: the noisy auxiliaries as written",
    "ref": "reference albedo, normal, depth, position; prefilter=off (the bound)",
    "ref-albedo": "reference albedo only; the rest as shipped",
    "ref-normal": "reference normal only; the rest as shipped",
    "oidn-aux": "albedo and normal prefiltered by OIDN's aux filters (albedo above 1 added "
    "back), zero variance; depth and position prefiltered as shipped",
    "oidn-aux-clamp": "oidn-aux with the albedo clamped to [0, 1] as OIDN sees it",
}


class OidnAux:
    """OIDN's auxiliary prefilter: an ``RT`` filter per buffer kind with only that image
    (``albedo`` or ``normal``) and ``output`` set, reused across images."""

    def __init__(self) -> None:
        import pyoidn

        self.pyoidn = pyoidn
        self.device = pyoidn.Device()
        self.device.commit()
        self.filters: dict[str, Any] = {}

    def __call__(self, kind: str, image: torch.Tensor) -> tuple[torch.Tensor, float, float]:
        """``(3, H, W)`` filtered ``kind`` image, the seconds of ``commit`` (network set-up
        for the image size: once per size in a renderer) and of ``execute``."""
        pyoidn = self.pyoidn
        lo = 0.0 if kind == "albedo" else -1.0
        x = np.ascontiguousarray(image.clamp(lo, 1.0).permute(1, 2, 0).numpy(), np.float32)
        out = np.empty_like(x)
        flt = self.filters.get(kind)
        if flt is None:
            flt = self.filters[kind] = pyoidn.Filter(self.device, pyoidn.OIDN_FILTER_TYPE_RT)
        t0 = time.perf_counter()
        flt.set_image(kind, x, pyoidn.OIDN_FORMAT_FLOAT3)
        flt.set_image(pyoidn.OIDN_IMAGE_OUTPUT, out, pyoidn.OIDN_FORMAT_FLOAT3)
        flt.set_quality(pyoidn.OIDN_QUALITY_HIGH)
        flt.commit()
        t1 = time.perf_counter()
        flt.execute()
        t2 = time.perf_counter()
        err = self.device.get_error()
        if err is not None:
            raise RuntimeError(f"OIDN {kind} prefilter: {err}")
        return torch.from_numpy(out).permute(2, 0, 1).contiguous(), t1 - t0, t2 - t1


def with_buffers(b: FeatureBuffers, new: Mapping[str, torch.Tensor]) -> FeatureBuffers:
    """A copy of ``b`` with ``new`` buffers set."""
    return dataclasses.replace(b, buffers={**b.buffers, **new})


def from_ref(b: FeatureBuffers, ref: FeatureBuffers, names: Sequence[str]) -> FeatureBuffers:
    """``b`` with ``names`` (and their variances, where the reference has them) from ``ref``;
    a name the reference lacks is left as it is in ``b``."""
    new = {}
    for n in names:
        for k in (n, f"{n}_var"):
            if k in ref:
                new[k] = ref[k]
    return with_buffers(b, new)


def measure_item(
    item: bench_ood.Item, variants: Sequence[str], aux: OidnAux | None
) -> tuple[list[bench_ood.Row], dict[str, Any]]:
    """bench_ood's ``kpcn`` and OIDN rows of one item plus one row per variant."""
    rows, extra = bench_ood.measure(item, [SHIPPED, BASELINE], {}, with_flip=False)
    rows = [r for r in rows if r.method in (SHIPPED, BASELINE)]
    b = load_buffers(item.path, part=item.part)
    ref = load_buffers(item.reference)
    mp = b.height * b.width / 1e6

    def aux_mse(n: str, x: torch.Tensor) -> float:
        """MSE against the reference's ``n``; albedo clamped to [0, 1] on both sides (what a
        prefilter of OIDN's kind addresses; the few glossy-lobe values above 1 would decide
        it otherwise)."""
        y = ref[n]
        if n == "albedo":
            x, y = x.clamp(0, 1), y.clamp(0, 1)
        return float((x - y).double().square().mean())

    for n in OIDN_AUX:
        if n in b and n in ref:
            extra[f"{n}_mse_noisy"] = aux_mse(n, b[n])
    builds: dict[str, Callable[[], tuple[FeatureBuffers, str] | str]] = {}
    builds["off"] = lambda: (b, "off")
    builds["ref"] = lambda: (from_ref(b, ref, REF_FEATURES), "off")
    for n in ("albedo", "normal"):
        builds[f"ref-{n}"] = lambda n=n: (
            (from_ref(b, ref, [n]), "adaptive") if n in ref else f"reference has no {n}"
        )

    filtered: dict[str, torch.Tensor] = {}

    def oidn_aux(clamped: bool) -> tuple[FeatureBuffers, str] | str:
        assert aux is not None
        if not filtered:  # once per item for both variants
            for n in OIDN_AUX:
                if n not in b:
                    continue
                filtered[n], commit, execute = aux(n, b[n])
                extra[f"oidn_{n}_commit_seconds"] = commit
                extra[f"oidn_{n}_seconds"] = execute
                extra[f"oidn_{n}_s_per_mp"] = execute / mp
        new = dict(filtered)
        for n in new:
            if n in ref:
                extra[f"{n}_mse_oidn"] = aux_mse(n, new[n])
        if not clamped and "albedo" in new:
            new["albedo"] = new["albedo"] + (b["albedo"] - b["albedo"].clamp(0, 1))
        for n in list(new):
            new[f"{n}_var"] = torch.zeros_like(new[n][:1])
        return with_buffers(b, new), "adaptive"

    builds["oidn-aux"] = lambda: oidn_aux(clamped=False)
    builds["oidn-aux-clamp"] = lambda: oidn_aux(clamped=True)
    for v in variants:
        if v == "shipped":
            k = bench_ood.value(rows, item.set, item.image, item.spp, SHIPPED)
            assert k is not None
            rows.append(bench_ood.Row(**{**asdict(k), "method": v}))
            continue
        row = bench_ood.Row(item.set, item.image, item.spp, v)
        built = builds[v]()
        if isinstance(built, str):
            row.refused = built
            rows.append(row)
            continue
        buffers, prefilter = built
        try:
            res = denoise(buffers, "kpcn", params={"prefilter": prefilter}, device="cpu")
        except McdenoiseError as err:
            row.refused = bench_ood.reason(err, item.path)
            rows.append(row)
            continue
        row.relmse, row.ssim = relmse(res.image, ref["color"]), ssim(res.image, ref["color"])
        row.s_per_mp = res.seconds / mp
        rows.append(row)
    return rows, extra


def speed(item: bench_ood.Item, repeat: int, reps: int) -> dict[str, float]:
    """Seconds per megapixel (best of ``reps``, 1 thread) of OIDN (colour, as bench_ood runs
    it), OIDN's albedo and normal filters, and ``kpcn`` as shipped and with ``prefilter=off``
    on ``item`` tiled ``repeat`` × ``repeat`` times (4: 1024² from the 256² set)."""
    b = load_buffers(item.path, part=item.part)
    b = with_buffers(b, {k: v.repeat(1, repeat, repeat) for k, v in b.buffers.items()})
    mp = b.height * b.width / 1e6
    aux = OidnAux()
    runs: dict[str, Callable[[], float]] = {
        "oidn (colour)": lambda: denoise(b, "oidn", device="cpu").seconds,
        "OIDN albedo filter": lambda: aux("albedo", b["albedo"])[2],
        "OIDN normal filter": lambda: aux("normal", b["normal"])[2],
        "kpcn shipped (adaptive)": lambda: denoise(b, "kpcn", device="cpu").seconds,
        "kpcn prefilter=off": lambda: (
            denoise(b, "kpcn", params={"prefilter": "off"}, device="cpu").seconds
        ),
    }
    out = {}
    for name, run in runs.items():
        run()  # warm-up (weights, OIDN filter set-up)
        out[name] = min(run() for _ in range(reps)) / mp
    return out


# --- summaries -----------------------------------------------------------------------------------


def ratio(rows: Sequence[bench_ood.Row], key: tuple[str, str, int], v: str) -> float | None:
    r = bench_ood.value(rows, *key, v)
    o = bench_ood.value(rows, *key, BASELINE)
    if r is None or o is None or r.relmse is None or not o.relmse:
        return None
    return r.relmse / o.relmse


def tables(
    rows: Sequence[bench_ood.Row],
    extra: Mapping[str, Any],
    sets: Sequence[str],
    levels: Sequence[int],
    variants: Sequence[str],
) -> tuple[str, dict[str, Any]]:
    """Markdown tables and the summary of a run."""
    broken = bench_ood.broken_baseline(rows, extra)
    lines: list[str] = []
    summary: dict[str, Any] = {}
    for set_ in sets:
        images = sorted({r.image for r in rows if r.set == set_})
        if not images:
            continue
        sound = [i for i in images if all((set_, i, s) not in broken for s in levels)]
        # the scenes every variant ran on (so that the means compare like with like)
        common = [i for i in sound
                  if all(ratio(rows, (set_, i, s), v) is not None for v in variants for s in levels)]  # fmt: skip
        left = [i.removeprefix("ood_") for i in sound if i not in common]
        lines += [f"### `{set_}`: `kpcn` relMSE / OIDN's, geometric mean over the "
                  f"{len(common)} scenes where OIDN is sound and every variant ran"
                  + (f" (not {', '.join(left)}; [n: x] is the mean over the n sound scenes "
                     "the variant ran on)" if left else ""), "",
                  "| variant | " + " | ".join(f"{s} spp" for s in levels)
                  + " | worst scene, 4 spp | kpcn s/MP |",
                  "|---|" + "---|" * (len(levels) + 2)]  # fmt: skip
        per_set: dict[str, Any] = {}
        for v in variants:
            cells, per = [], {}
            for s in levels:
                rs = [ratio(rows, (set_, i, s), v) for i in common]
                g = geometric_mean(rs) if common else None
                ok = [x for x in (ratio(rows, (set_, i, s), v) for i in sound) if x is not None]
                g_ran = geometric_mean(ok) if ok else None
                per[str(s)] = {"ratio": g, "scenes": len(common), "ratio_ran": g_ran,
                               "scenes_ran": len(ok)}  # fmt: skip
                c = bench_ood.fmt(g, ".2f")
                if len(ok) > len(common):
                    c += f" [{len(ok)}: {bench_ood.fmt(g_ran, '.2f')}]"
                cells.append(c)
            first = [(ratio(rows, (set_, i, levels[0]), v), i) for i in common]
            first = [(x, i) for x, i in first if x is not None]
            worst = max(first) if first else (None, "-")
            secs = [r.s_per_mp for r in rows if r.set == set_ and r.method == v and r.s_per_mp]
            med = statistics.median(secs) if secs else None
            per_set[v] = per
            lines.append(f"| `{v}` | {' | '.join(cells)} | {bench_ood.fmt(worst[0], '.2f')} "
                         f"({worst[1].removeprefix('ood_')}) | {bench_ood.fmt(med, '.2f')} |")  # fmt: skip
        secs = [r.s_per_mp for r in rows if r.set == set_ and r.method == BASELINE and r.s_per_mp]
        med = statistics.median(secs) if secs else None
        ones = " | ".join("1" for _ in levels)
        lines.append(f"| (`oidn` itself, colour) | {ones} | - | {bench_ood.fmt(med, '.2f')} |")
        summary[set_] = per_set
        lines.append("")
        lines += [f"#### `{set_}` per scene: relMSE / OIDN's at " + " / ".join(map(str, levels))
                  + " spp", "",
                  "| scene | " + " | ".join(f"`{v}`" for v in variants) + " |",
                  "|---|" + "---|" * len(variants)]  # fmt: skip
        for i in images:
            cells = []
            for v in variants:
                xs = [ratio(rows, (set_, i, s), v) for s in levels]
                cells.append(" / ".join(bench_ood.fmt(x, ".2f") for x in xs))
            note = " (OIDN not sound)" if any((set_, i, s) in broken for s in levels) else ""
            lines.append(f"| {i.removeprefix('ood_')}{note} | {' | '.join(cells)} |")
        lines.append("")
        # auxiliary errors and OIDN aux filter times
        lines += [f"#### `{set_}`: auxiliary MSE against the reference's (noisy → OIDN "
                  "aux filter), mean over scenes, and OIDN aux filter seconds per megapixel "
                  "(`execute`, median; 1 thread)", "",
                  "| spp | albedo MSE (in [0, 1]) | normal MSE | OIDN albedo s/MP | OIDN normal s/MP |",
                  "|---|---|---|---|---|"]  # fmt: skip
        for s in levels:
            es = [extra.get(f"{set_}/{i}/{s}", {}) for i in images]

            def mean(key: str, es: list[dict[str, Any]] = es) -> float | None:
                xs = [e[key] for e in es if e.get(key) is not None]
                return statistics.fmean(xs) if xs else None

            def pair(n: str, mean: Callable[[str], float | None] = mean) -> str:
                text = (f"{bench_ood.fmt(mean(f'{n}_mse_noisy'), '.5f')} → "
                        f"{bench_ood.fmt(mean(f'{n}_mse_oidn'), '.5f')}")  # fmt: skip
                return text

            def median(key: str, es: list[dict[str, Any]] = es) -> str:
                xs = [e[key] for e in es if e.get(key) is not None]
                return bench_ood.fmt(statistics.median(xs) if xs else None, ".2f")

            lines.append(f"| {s} | {pair('albedo')} | {pair('normal')} | "
                         f"{median('oidn_albedo_s_per_mp')} | {median('oidn_normal_s_per_mp')} |")  # fmt: skip
        lines.append("")
    return "\n".join(lines), summary


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=bench_ood.DATA)
    ap.add_argument("--sets", default="aov256")
    ap.add_argument("--levels", default="4,16,64")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--scenes", default="", help="only images whose id contains one of these")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--markdown", type=Path, default=None)
    ap.add_argument("--from-json", type=Path, action="append", default=[], metavar="RUN.json",
                    help="tables of earlier --json runs instead of measuring")  # fmt: skip
    ap.add_argument("--speed", type=int, default=0, metavar="REPS",
                    help="instead of measuring: time OIDN's colour and aux filters and kpcn "
                    "(best of REPS, 1 thread) on the first image, tiled to --speed-tile²×")  # fmt: skip
    ap.add_argument("--speed-tile", type=int, default=4, help="tiling of the --speed image")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    levels = [int(x) for x in args.levels.split(",")]
    sets = [s for s in args.sets.split(",") if s]
    variants = [v for v in args.variants.split(",") if v]
    bad = [v for v in variants if v not in VARIANTS] + [s for s in sets if s not in bench_ood.SETS]
    if bad:
        raise SystemExit(f"unknown variant or set: {', '.join(bad)}")
    scenes = [s for s in args.scenes.split(",") if s]
    rows: list[bench_ood.Row] = []
    extra: dict[str, Any] = {}
    commit = None
    for path in args.from_json:
        old = json.loads(path.read_text())
        rows += [bench_ood.Row(**r) for r in old["rows"]]
        extra.update(old["extra"])
        commit = old.get("commit")
    todo = [] if args.from_json else [
        it for s in sets for it in bench_ood.items_of(args.data, s, levels, scenes)]  # fmt: skip
    if args.speed:
        it = todo[0]
        res = speed(it, args.speed_tile, args.speed)
        side = f"{256 * args.speed_tile}" if it.set.endswith("256") else "?"
        print(f"{it.set} {it.image} {it.spp} spp tiled {args.speed_tile}x{args.speed_tile} "
              f"({side}²), best of {args.speed}, 1 thread: s/MP")  # fmt: skip
        for name, v in res.items():
            print(f"  {name:26s} {v:6.2f}")
        return 0
    aux = OidnAux() if any(v.startswith("oidn-aux") for v in variants) and todo else None
    print(f"{len(todo)} items in {', '.join(sets)}; variants {', '.join(variants)}", flush=True)
    t0 = time.perf_counter()
    for n, it in enumerate(todo, 1):
        r, e = measure_item(it, variants, aux)
        rows += r
        extra[f"{it.set}/{it.image}/{it.spp}"] = e
        cells = " ".join(f"{v} {bench_ood.fmt(ratio(r, (it.set, it.image, it.spp), v), '.2f')}"
                         for v in variants)  # fmt: skip
        print(f"[{n}/{len(todo)} {time.perf_counter() - t0:.0f} s] {it.set} {it.image} "
              f"{it.spp} spp: {cells}", flush=True)  # fmt: skip
    text, summary = tables(rows, extra, sets, levels, variants)
    print("\n" + text)
    if args.markdown:
        write_text_atomic(args.markdown, text)
    if args.json:
        write_text_atomic(args.json, json.dumps(bench_ood.clean({
            "data": str(args.data), "sets": sets, "levels": levels, "variants": variants,
            "commit": commit or bench_ood.git_commit(), "seconds": time.perf_counter() - t0,
            "summary": summary, "extra": extra, "rows": [asdict(r) for r in rows],
        }), indent=1))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

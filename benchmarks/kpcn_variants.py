"""``kpcn`` against OIDN per image, under input and parameter variants (issue 21 probes).

Each variant is ``LABEL=KEY:VALUE,KEY:VALUE...`` with keys:

* ``model``: run folder or model file (default ``shipped``);
* ``prefilter`` (``auto``/``all``/``off``) and ``exposure`` (``auto``/``off``): the kpcn
  method parameters (default: the method's defaults);
* ``source``: ``basic`` (default: colour, albedo and normal only, as a Mitsuba ``aov`` file
  has them) or ``full`` (the render as it is; render layout only);
* ``clean``: ``albedo``, ``normal`` or ``albedo+normal``: swap in the reference's buffers
  (noise-free auxiliaries; render layout only);
* ``scale``: multiply the colour by this factor and divide the result by it (exposure);
* ``normals``: ``zxy`` (axes permuted) or ``neg`` (negated): another normal convention.

Data: a ``mcdenoise render`` folder (``<id>.exr`` with parts ``spp<n>``, ``ref/<id>.exr``),
or with ``--aov REFDIR`` a folder of plain Mitsuba ``aov`` files ``<id>_spp<n>.exr`` whose
references are ``REFDIR/ref/<id>.exr`` (the layout of ``benchmarks/render_ood.py``). OIDN
(albedo + normal) runs on the same input; relMSE (ε = 0.01) and SSIM from
:mod:`mcdenoise.eval.metrics`. Printed: per image and level ``label=relMSE/OIDN's/SSIM``, then
per level and variant the geometric mean of the ratios, the worst one and the mean SSIM
difference to OIDN (``--exclude`` leaves images out of those summaries, e.g. where OIDN
itself fails).

    python benchmarks/kpcn_variants.py data/generated/heldout --levels 4,16 \\
        off=prefilter:off,exposure:off auto=exposure:off clean=clean:albedo+normal,prefilter:off
    python benchmarks/kpcn_variants.py data/generated/ood/aov256 --aov data/generated/ood/r256 \\
        old=prefilter:off,exposure:off new=
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

import torch

from mcdenoise.denoise import denoise
from mcdenoise.eval.metrics import relmse, ssim
from mcdenoise.io import load_buffers
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.train.patches import scan_dataset

KEYS = ("model", "prefilter", "exposure", "source", "clean", "scale", "normals")
NORMALS = {"zxy": lambda n: n[[2, 0, 1]], "neg": lambda n: -n}


def parse_variant(text: str) -> tuple[str, dict[str, str]]:
    label, sep, rest = text.partition("=")
    pairs = [p.partition(":") for p in rest.split(",") if p]
    spec = {k: v for k, _, v in pairs}
    bad = [k for k in spec if k not in KEYS]
    if not sep or not label or bad or any(not v for v in spec.values()):
        raise argparse.ArgumentTypeError(
            f"variant wants LABEL=KEY:VALUE,... with keys {', '.join(KEYS)}, got {text!r}"
        )
    return label, spec


def items(data: Path, aov_ref: Path | None, levels: list[int], only: set[str]):
    """(image, spp, buffers, reference buffers, is_render) per image and level."""
    if aov_ref is not None:
        for spp in levels:
            for path in sorted(data.glob(f"*_spp{spp}.exr")):
                image = path.name.rsplit("_spp", 1)[0]
                if only and image not in only:
                    continue
                yield (
                    image,
                    spp,
                    load_buffers(path),
                    load_buffers(aov_ref / "ref" / path.name.replace(f"_spp{spp}", "")),
                    False,
                )
        return
    for e in scan_dataset(data, levels):
        if only and e.image not in only:
            continue
        b = load_buffers(e.path, part=e.part)
        if "albedo" in b:
            yield e.image, e.spp, b, load_buffers(e.reference), True


def variant_input(b: FeatureBuffers, ref: FeatureBuffers, render: bool, spec: dict[str, str]):
    if spec.get("source", "basic") == "full":
        if not render:
            raise SystemExit("source:full needs the render layout")
        x = dict(b.buffers)
    else:
        x = {k: b[k] for k in ("color", "albedo", "normal")}
    for name in spec.get("clean", "").split("+") if spec.get("clean") else []:
        if not render:
            raise SystemExit("clean needs the render layout (references with auxiliaries)")
        x[name] = ref[name]
    if "normals" in spec:
        x["normal"] = NORMALS[spec["normals"]](x["normal"])
    scale = float(spec.get("scale", 1.0))
    if scale != 1.0:
        x["color"] = x["color"] * scale
        if "color_var" in x:
            x["color_var"] = x["color_var"] * scale * scale
    profile = b.profile if spec.get("source") == "full" else "mitsuba"
    return FeatureBuffers(x, spp=b.spp, profile=profile), scale


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data", type=Path)
    ap.add_argument("variants", type=parse_variant, nargs="+")
    ap.add_argument("--aov", type=Path, default=None, help="canonical folder with ref/")
    ap.add_argument("--levels", default="4,16")
    ap.add_argument("--images", default="")
    ap.add_argument("--exclude", default="", help="images left out of the summaries")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    levels = [int(s) for s in args.levels.split(",")]
    only = set(filter(None, args.images.split(",")))
    exclude = set(filter(None, args.exclude.split(",")))
    res: dict[tuple[str, int], dict[str, tuple[float, float]]] = {}
    for image, spp, b, refb, render in items(args.data, args.aov, levels, only):
        ref = refb["color"]
        o = denoise(b, "oidn").image
        row = {"oidn": (relmse(o, ref), ssim(o, ref))}
        for label, spec in args.variants:
            x, scale = variant_input(b, refb, render, spec)
            params: dict[str, Any] = {
                k: spec[k] for k in ("model", "prefilter", "exposure") if k in spec
            }
            out = denoise(x, "kpcn", params=params).image / scale
            row[label] = (relmse(out, ref), ssim(out, ref))
        res[(image, spp)] = row
        on = row["oidn"][0]
        cells = " ".join(f"{k}={v[0] / on:.2f}x/{v[1]:.3f}" for k, v in row.items() if k != "oidn")
        print(f"{image:26s} {spp:>3}  oidn {on:.5f}/{row['oidn'][1]:.3f}  {cells}", flush=True)
    for spp in levels:
        rows = [r for (i, s), r in res.items() if s == spp and i not in exclude]
        if not rows:
            continue
        cells = []
        for label, _ in args.variants:
            ratios = [r[label][0] / r["oidn"][0] for r in rows]
            g = math.exp(sum(math.log(max(x, 1e-12)) for x in ratios) / len(ratios))
            ds = sum(r[label][1] - r["oidn"][1] for r in rows) / len(rows)
            cells.append(f"{label} {g:.3f} (worst {max(ratios):.2f}, SSIM {ds:+.3f})")
        print(f"{spp} spp, {len(rows)} images, kpcn/OIDN geomean: " + "; ".join(cells))
    return 0


if __name__ == "__main__":
    sys.exit(main())

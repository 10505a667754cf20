"""Half buffers and the reference-free error estimate (issue 24): what halves cost to render,
and how well the estimate matches the true error on held-out renders.

``python benchmarks/bench_estimate.py render-cost [--scenes ...] [--reps 3]``
    The extra render time of ``--halves``: every scene is loaded once (``llvm_ad_rgb``, 128²,
    4/16/64 spp, one thread), rendered once per mode to compile the kernels, then ``--reps``
    times per mode, alternating, so load on a shared machine hits both alike; the time is the
    noisy levels' render seconds without Dr.Jit's kernel compilation (``jit_seconds``).
    Prints per scene the median seconds with and without halves and the ratio, and the ratio
    of the sums.

``python benchmarks/bench_estimate.py file-size DIR [DIR ...]``
    The size of every level of the render folders saved with every guide halved, with the
    colour's halves only (renders before issue 36) and without halves (ZIP, float32).

``python benchmarks/bench_estimate.py shared-guides [--trials 64] [--size 128] [--spp 4]``
    Filters guided by an albedo as noisy as the colour (a texture finer than a pixel), the
    guide shared by both halves or halved (:func:`shared_guides_study`): the bias of the
    estimate in standard errors and the estimate over the truth.

``python benchmarks/bench_estimate.py synthetic [--trials 64] [--size 128] [--spp 8]``
    The estimator (:mod:`mcdenoise.eval.estimate`) on synthetic images whose truth is known:
    a smooth image with edges and fine texture, every pixel's two halves the means of
    ``spp/2`` samples ``μ·Z`` with ``E[Z] = 1`` and Gaussian, log-normal (σ = 1.5) or rare
    bright outlier noise (``Z`` 200× larger with probability 0.005), each half's variance of
    the mean from its samples. Candidate filters: identity, Gaussian blurs (σ = 0.75, 1.5,
    3) and a 3×3 median (nonlinear). Prints per noise (a) the bias of the image-level
    estimate of the squared error of ``(D(A) + D(B))/2`` over trials, in standard errors, per
    filter; (b) the share of 16×16 blocks where the estimate picks the candidate the true
    error picks, and the share of candidate pairs per block it orders as the truth does.

``python benchmarks/bench_estimate.py heldout [--data DIR] [--spp 4,16,64] [--methods ...]
[--json OUT]``
    The estimate against the truth on held-out renders with halves and references
    (``data/generated/heldout-halves-3000``, ``data/recipes/heldout-halves.md``): per image,
    level and method, the method on the full buffer (what ``mcdenoise denoise`` writes) and on
    each half; the estimate (:func:`~mcdenoise.eval.estimate.estimate_from_outputs`, what
    ``--estimate-error`` writes) against the true relMSE of the full output, and of the mean
    of the filtered halves (which the estimate is unbiased for). The true relMSE is also
    given with the reference's own noise removed (``(x − r)² − Var r``: the reference's
    variance of the mean, from its ``color_var``), since a 4096-spp reference still adds
    error that no reference-free estimate sees. Prints per level the share of (image,
    method) pairs whose estimate is within a factor 1.5 of the truth, the mean over images
    of Spearman's ρ between the estimated and the true ranking of the methods, and per
    method the geometric mean of estimate / truth and of the full output's relMSE over the
    halves-mean's (the carry-over). ``--json`` keeps every record (re-analyse with
    ``--from-json``); ``--cache DIR`` keeps the outputs, so the estimators of
    :func:`variant_estimates` (normalisers, common terms) are measured again without
    denoising; ``--brief`` prints one line per estimator, ``--only`` picks some, ``--block``
    sets the block of the standard errors (the "truth within 2 SE" column).
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CURATED = ("cornell", "dof_row", "textured_floors", "glossy_env", "sun_outdoor")


def _level_seconds(rendered) -> float:
    return sum(r["increment_seconds"] - r.get("jit_seconds", 0.0) for r in rendered.level_records)


def render_cost(args: argparse.Namespace) -> int:
    import tempfile

    from mcdenoise.render.config import RenderConfig
    from mcdenoise.render.jobs import jobs_from_specs
    from mcdenoise.render.mitsuba_setup import ensure_variant
    from mcdenoise.render.passes import render_image
    from mcdenoise.render.scene_spec import load_spec
    from mcdenoise.threads import set_render_threads

    variant = ensure_variant(args.variant)
    set_render_threads(args.threads)
    specs = [load_spec(ROOT / "data" / "scenes" / f"{s}.toml") for s in args.scenes]
    spp = tuple(int(v) for v in args.spp.split(","))
    totals = {False: 0.0, True: 0.0}
    with tempfile.TemporaryDirectory() as tmp:
        cfgs = {
            h: RenderConfig(
                out=Path(tmp),
                width=args.res,
                height=args.res,
                spp=spp,
                ref_spp=1,
                variant=variant,
                halves=h,
            )
            for h in (False, True)
        }
        print(f"{'scene':18s} {'plain s':>8s} {'halves s':>8s} {'ratio':>6s}")
        for job in jobs_from_specs(specs, seed=args.seed):
            times: dict[bool, list[float]] = {False: [], True: []}
            for rep in range(args.reps + 1):
                for h in (False, True) if rep % 2 == 0 else (True, False):
                    t = _level_seconds(render_image(job, cfgs[h], variant))
                    if rep:  # the first round compiles the kernels of both modes
                        times[h].append(t)
            med = {h: statistics.median(v) for h, v in times.items()}
            for h in med:
                totals[h] += med[h]
            print(f"{job.id:18s} {med[False]:8.3f} {med[True]:8.3f} {med[True] / med[False]:6.3f}")
    print(
        f"{'all':18s} {totals[False]:8.3f} {totals[True]:8.3f} {totals[True] / totals[False]:6.3f}"
    )
    return 0


def file_size(args: argparse.Namespace) -> int:
    """Bytes of every level of the render folders ``args.data`` saved (ZIP, float32) with
    every guide halved, with colour halves only, and without halves."""
    import tempfile

    from mcdenoise.io import load_buffers, probe_exr, save_buffers

    def halves(n: str) -> bool:
        return n.endswith(("_a", "_b", "_a_var", "_b_var"))

    layouts = {
        "every guide halved": lambda n: True,
        "colour halves only": lambda n: n.startswith("color") or not halves(n),
        "no halves": lambda n: not halves(n),
    }
    for folder in args.data:
        total = dict.fromkeys(layouts, 0)
        for f in sorted(Path(folder).glob("*.exr")):
            for part in (p.name for p in probe_exr(f)):
                fb = load_buffers(f, part=part)
                with tempfile.TemporaryDirectory() as tmp:
                    for k, keep in layouts.items():
                        path = Path(tmp) / "x.exr"
                        save_buffers(path, fb.subset([n for n in fb.names() if keep(n)]))
                        total[k] += path.stat().st_size
        for k, v in total.items():
            print(f"{folder}: {k:20s} {v / 1e6:8.2f} MB  {v / total['no halves']:.2f}x no halves")
    return 0


# --- synthetic validation -------------------------------------------------------------------
NOISES = ("gaussian", "lognormal", "outliers")


def synthetic_truth(size: int, device: str = "cpu"):
    """A ``(3, size, size)`` radiance image: smooth shading, a bright disc with a sharp edge,
    a fine checker texture in one quadrant, a dark corner (relMSE's ε matters there)."""
    import torch

    y, x = torch.meshgrid(
        torch.arange(size, dtype=torch.float64),
        torch.arange(size, dtype=torch.float64),
        indexing="ij",
    )
    base = 0.5 + 0.35 * torch.sin(x / 9) * torch.cos(y / 13)
    disc = ((x - 0.3 * size) ** 2 + (y - 0.6 * size) ** 2 < (0.18 * size) ** 2).double()
    checker = ((x // 2 + y // 2) % 2) * ((x > size / 2) & (y < size / 2)).double()
    dark = ((x > 0.75 * size) & (y > 0.75 * size)).double()
    lum = (base + 1.5 * disc + 0.4 * checker) * (1 - 0.95 * dark)
    tint = torch.tensor([1.0, 0.8, 0.6], dtype=torch.float64)[:, None, None]
    return (lum[None] * tint).to(device)


def synthetic_halves(mu, spp: int, noise: str, trials: int, generator):
    """``trials`` renders of ``mu``: halves A, B ``(T, 3, H, W)`` (means of ``spp/2`` samples
    ``μ·Z``, one ``Z`` per sample shared by the channels as a path's throughput is) and their
    variances of the mean."""
    import torch

    n = spp // 2
    shape = (2, trials, n, 1, *mu.shape[1:])
    g = torch.randn(shape, generator=generator, dtype=torch.float64)
    if noise == "gaussian":
        z = 1 + 0.8 * g
    elif noise == "lognormal":
        z = torch.exp(1.5 * g - 1.5**2 / 2)
    elif noise == "outliers":
        k, p = 200.0, 0.005
        hit = (torch.rand(shape, generator=generator, dtype=torch.float64) < p).double()
        z = (1 + 0.3 * g + k * hit) / (1 + k * p)
    else:
        raise ValueError(noise)
    samples = mu * z  # (2, T, n, 3, H, W)
    mean = samples.mean(2)
    var = samples.var(2, unbiased=True) / n if n > 1 else torch.zeros_like(mean)
    return mean[0], mean[1], var[0], var[1]


def candidate_filters():
    """Name -> filter on ``(T, 3, H, W)`` tensors (reflect padding)."""
    import torch
    import torch.nn.functional as F

    def gaussian(sigma: float):
        r = int(3 * sigma + 0.5)
        t = torch.arange(-r, r + 1, dtype=torch.float64)
        k = torch.exp(-(t**2) / (2 * sigma**2))
        k = k / k.sum()

        def f(x):
            c = x.shape[1]
            xp = F.pad(x, (r, r, r, r), mode="reflect")
            kx = k.to(x)[None, None, None, :].repeat(c, 1, 1, 1)
            ky = k.to(x)[None, None, :, None].repeat(c, 1, 1, 1)
            return F.conv2d(F.conv2d(xp, kx, groups=c), ky, groups=c)

        return f

    def median3(x):
        xp = F.pad(x, (1, 1, 1, 1), mode="reflect")
        patches = xp.unfold(2, 3, 1).unfold(3, 3, 1)
        return patches.reshape(*patches.shape[:4], 9).median(-1).values

    return {
        "identity": lambda x: x,
        "gauss0.75": gaussian(0.75),
        "gauss1.5": gaussian(1.5),
        "gauss3": gaussian(3.0),
        "median3": median3,
    }


def synthetic_study(
    noise: str, *, trials: int = 64, size: int = 128, spp: int = 8, block: int = 16, seed: int = 0
) -> dict:
    """Bias and ranking of the estimate on one noise model (see the module docstring)."""
    import torch

    from mcdenoise.eval.estimate import block_means, cross_error, squared_error

    gen = torch.Generator().manual_seed(seed)
    mu = synthetic_truth(size)
    a, b, va, vb = synthetic_halves(mu, spp, noise, trials, gen)
    bias: dict[str, float] = {}
    bias_wins: dict[str, tuple[float, float]] = {}
    spread: dict[str, tuple[float, float]] = {}
    est_blocks, true_blocks = [], []
    for name, f in candidate_filters().items():
        da, db = f(a), f(b)
        est = squared_error(da, db, a, b)
        true = ((da + db) / 2 - mu).square()
        diff = (est - true).mean(dim=(1, 2, 3))  # per trial
        bias[name] = float(diff.mean() / (diff.std() / trials**0.5))
        with_var = (cross_error(da, db, a, b, va, vb) - true).mean(dim=(1, 2, 3))
        prod = (a - da) * (b - db)  # the winsorised variant of the held-out study
        cap = 9 * (va * vb).sqrt()
        wins = est - prod + torch.maximum(torch.minimum(prod, cap), -cap)
        dw = (wins - true).mean(dim=(1, 2, 3))
        bias_wins[name] = (
            float(dw.mean() / (dw.std() / trials**0.5)),
            float(dw.mean()) / float(true.mean()),
        )
        scale = float(true.mean())
        spread[name] = (float(diff.std()) / scale, float(with_var.std()) / scale)
        est_blocks.append(torch.stack([block_means(e, block)[0] for e in est]))
        true_blocks.append(torch.stack([block_means(t, block)[0] for t in true]))
    est_b, true_b = torch.stack(est_blocks), torch.stack(true_blocks)  # (K, T, by, bx)
    argmin = float((est_b.argmin(0) == true_b.argmin(0)).double().mean())
    k = est_b.shape[0]
    agree, pairs = 0.0, 0
    for i in range(k):
        for j in range(i + 1, k):
            agree += float(((est_b[i] < est_b[j]) == (true_b[i] < true_b[j])).double().mean())
            pairs += 1
    return {
        "noise": noise,
        "bias_in_se": bias,
        "bias_wins": bias_wins,
        "spread": spread,
        "argmin_agree": argmin,
        "pair_agree": agree / pairs,
    }


def synthetic(args: argparse.Namespace) -> int:
    for noise in args.noises:
        r = synthetic_study(
            noise, trials=args.trials, size=args.size, spp=args.spp, block=args.block
        )
        biases = ", ".join(f"{k} {v:+.2f}" for k, v in r["bias_in_se"].items())
        spreads = ", ".join(f"{k} {u:.3f}/{v:.3f}" for k, (u, v) in r["spread"].items())
        print(
            f"{noise:10s} spp {args.spp}: relative spread over trials (A-B)²/variance "
            f"buffers: {spreads}"
        )
        wins = ", ".join(f"{k} {z:+.1f} ({rel:+.1%})" for k, (z, rel) in r["bias_wins"].items())
        print(f"{noise:10s} spp {args.spp}: winsorised product: bias/SE (relative) {wins}")
        print(
            f"{noise:10s} spp {args.spp}: bias/SE {biases}; per {args.block}x{args.block} "
            f"block: best candidate agrees {r['argmin_agree']:.3f}, "
            f"pairs ordered alike {r['pair_agree']:.3f}"
        )
    return 0


# --- shared noisy guides (issue 36) ----------------------------------------------------------
def textured_samples(size: int, spp: int, trials: int, generator):
    """A sub-pixel texture under smooth light, sampled per half: every sample hits a bright
    (0.9) or a dark (0.1) texel, the bright one with a probability ``p`` that varies over the
    image (the texel mix of the pixel), and carries light ``L·z`` (``z = 1 + 0.5 g``). Returns
    the truth ``μ = L·E[α]`` ``(3, H, W)``, and per half (``(T, 3, H, W)`` each) the colour
    means A, B and the albedo means αA, αB: each half's albedo is as noisy as its colour and
    correlated with it, as on a real texture finer than a pixel."""
    import torch

    y, x = torch.meshgrid(
        torch.arange(size, dtype=torch.float64),
        torch.arange(size, dtype=torch.float64),
        indexing="ij",
    )
    light = 0.6 + 0.4 * torch.sin(x / 11) * torch.cos(y / 7)
    p = 0.5 + 0.45 * torch.sin(x / 3.0 + y / 5.0)  # the bright texels' share per pixel
    lo, hi = 0.1, 0.9
    tint = torch.tensor([1.0, 0.8, 0.6], dtype=torch.float64)[:, None, None]
    mu = (light * (lo + (hi - lo) * p))[None] * tint
    n = spp // 2
    shape = (2, trials, n, 1, size, size)
    bright = (torch.rand(shape, generator=generator, dtype=torch.float64) < p).double()
    alpha = lo + (hi - lo) * bright  # (2, T, n, 1, H, W)
    z = 1 + 0.5 * torch.randn(shape, generator=generator, dtype=torch.float64)
    color = (light * alpha * z) * tint
    albedo = alpha.expand(*shape[:3], 3, size, size) * tint / tint  # grey texels, 3 channels
    c, a = color.mean(2), albedo.mean(2)
    return mu, c[0], c[1], a[0], a[1]


def guided_filters():
    """Name -> ``f(colour, guide)`` on ``(T, 3, H, W)``: filters that read an albedo guide,
    as the learned and classical denoisers do. ``demodulate``: divide by the guide, blur
    (Gaussian σ = 1.5), multiply back (KPCN's and SVGF's albedo demodulation);
    ``cross-bilateral``: a 7×7 Gaussian (σ = 2) weighted by the guide's difference
    (σ = 0.1)."""
    import torch
    import torch.nn.functional as F

    gauss = candidate_filters()["gauss1.5"]

    def demodulate(x, g):
        return g * gauss(x / (g + 1e-3))

    def cross_bilateral(x, g, r: int = 3, sigma_s: float = 2.0, sigma_g: float = 0.1):
        xp = F.pad(x, (r, r, r, r), mode="reflect")
        gp = F.pad(g, (r, r, r, r), mode="reflect")
        h, w = x.shape[-2:]
        num = torch.zeros_like(x)
        den = torch.zeros_like(x[:, :1])
        for dy in range(-r, r + 1):
            for dx in range(-r, r + 1):
                xs = xp[..., r + dy : r + dy + h, r + dx : r + dx + w]
                gs = gp[..., r + dy : r + dy + h, r + dx : r + dx + w]
                d2 = (gs - g).square().mean(1, keepdim=True)
                wgt = torch.exp(-(dx * dx + dy * dy) / (2 * sigma_s**2) - d2 / (2 * sigma_g**2))
                num += wgt * xs
                den += wgt
        return num / den

    return {"demodulate": demodulate, "cross-bilateral": cross_bilateral}


def shared_guides_study(*, trials: int = 32, size: int = 64, spp: int = 4, seed: int = 0) -> dict:
    """The estimate of filters guided by an albedo that is as noisy as the colour (a
    sub-pixel texture, :func:`textured_samples`), with the guide shared by both halves (the
    full buffer's albedo, what a file without ``albedo_a``/``albedo_b`` gives) and with the
    guide halved (each half filtered with its own albedo). Per filter and guide: the bias
    of the image-level estimate of the squared error of ``(D(A) + D(B))/2`` over trials, in
    standard errors, and the mean estimate over the mean truth."""
    import torch

    from mcdenoise.eval.estimate import squared_error

    gen = torch.Generator().manual_seed(seed)
    mu, a, b, ga, gb = textured_samples(size, spp, trials, gen)
    full = (ga + gb) / 2
    out: dict[str, dict[str, tuple[float, float]]] = {}
    for name, f in guided_filters().items():
        out[name] = {}
        for guide, (g_a, g_b) in (("shared", (full, full)), ("halved", (ga, gb))):
            da, db = f(a, g_a), f(b, g_b)
            est = squared_error(da, db, a, b).mean(dim=(1, 2, 3))
            true = ((da + db) / 2 - mu).square().mean(dim=(1, 2, 3))
            diff = est - true
            z = float(diff.mean() / (diff.std() / trials**0.5))
            out[name][guide] = (z, float(est.mean() / true.mean()))
    return out


def shared_guides(args: argparse.Namespace) -> int:
    r = shared_guides_study(trials=args.trials, size=args.size, spp=args.spp)
    print(
        f"sub-pixel texture, {args.spp} spp, {args.trials} trials of {args.size}²: bias of "
        "the estimate in standard errors (estimate / truth)"
    )
    for name, by in r.items():
        cells = ", ".join(f"{g} {z:+.1f} ({q:.2f})" for g, (z, q) in by.items())
        print(f"  {name:16s} {cells}")
    return 0


# --- held-out renders ------------------------------------------------------------------------
HELDOUT = ROOT / "data" / "generated" / "heldout-halves-3000"
METHODS = ("noisy", "nlm", "cross-bilateral", "kalantari-xbf", "kpcn", "oidn")
FACTOR = 1.5


def _relmse_terms(out, ref, ref_var):
    """(relMSE, relMSE with the reference's noise removed) of ``out`` against ``ref``."""
    from mcdenoise.losses import RELMSE_EPS

    den = ref.double().square() + RELMSE_EPS
    sq = (out.double() - ref.double()).square()
    raw = float((sq / den).mean())
    corr = float(((sq - ref_var.double()) / den).mean()) if ref_var is not None else raw
    return raw, corr


def heldout_records(
    data: Path,
    spp: list[int],
    methods: list[str],
    done: dict,
    *,
    ref_dir: Path | None = None,
    images: list[str] | None = None,
    cache: Path | None = None,
    block: int = 16,
    share_guides: bool = False,
    half_noise: str = "half",
) -> list[dict]:
    """One record per (image, level, method); ``done`` holds records already measured
    (keyed ``image/spp/method``), which are kept; ``cache``: a folder keeping every image's
    halves, reference and the methods' outputs (full and per half) as ``.pt``, so that other
    estimators are measured on the same outputs without denoising again. Every estimator of
    :func:`variant_estimates` is recorded as ``estimate_<name>``; ``estimate`` is what
    ``--estimate-error`` writes (normalised by the method's own output), ``estimate_shared``
    what ``mcdenoise eval`` without ``--ref`` reports for several outputs (the matched median
    of the outputs); both are the reported value (the upper bound where the estimate is below
    its noise, ``estimate_upper``/``estimate_shared_upper``). ``share_guides``: the feature
    halves (``albedo_a``...) are dropped first, so both halves share the full buffer's
    guides, as in a file written before issue 36."""
    import time

    import torch

    from mcdenoise.denoise import denoise
    from mcdenoise.errors import McdenoiseError
    from mcdenoise.eval.estimate import estimate_from_outputs, matched_normaliser, split_halves
    from mcdenoise.io import load_buffers
    from mcdenoise.io.buffers import sanitize
    from mcdenoise.render.manifest import load_manifest

    records = []
    for img in load_manifest(data)["images"]:
        if images and img["id"] not in images:
            continue
        ref_path = data / img["files"]["reference"]
        if ref_dir is not None:  # the same image id and seed rendered elsewhere with a reference
            ref_path = ref_dir / f"{img['id']}.exr"
        if not ref_path.is_file():
            print(f"{img['id']}: skipped: no reference {ref_path}", file=sys.stderr)
            continue
        ref_fb = load_buffers(ref_path)
        ref, ref_var = ref_fb["color"].double(), ref_fb.get("color_var")
        for level in spp:
            keys = [f"{img['id']}/{level}/{m}" for m in methods]
            if all(k in done for k in keys):
                records += [done[k] for k in keys]
                continue
            fb, _ = sanitize(load_buffers(data / img["files"]["noisy"], part=f"spp{level}"))
            if share_guides:
                for n in [n for n in fb.names() if n.split("_")[0] != "color"]:
                    if n.endswith(("_a", "_b", "_a_var", "_b_var")):
                        del fb.buffers[n]
            ha, hb = split_halves(fb)
            if half_noise == "full":  # each half told the full buffer's noise level
                for h in (ha, hb):
                    for n in [n for n in h.names() if n.endswith("_var")]:
                        h.buffers[n] = h.buffers[n] / 2
                    h.spp = fb.spp
            cfile = cache / f"{img['id']}_spp{level}.pt" if cache is not None else None
            outs: dict = {}
            if cfile is not None and cfile.is_file():
                outs = torch.load(cfile)["outs"]
            for method, key in zip(methods, keys):
                if method in outs:
                    continue
                t0 = time.perf_counter()
                try:
                    if method == "noisy":
                        full, out_a, out_b = fb["color"], ha["color"], hb["color"]
                    else:
                        full = denoise(fb, method, device="cpu").image
                        out_a = denoise(ha, method, device="cpu").image
                        out_b = denoise(hb, method, device="cpu").image
                except McdenoiseError as err:
                    print(f"{key}: skipped: {' '.join(str(err).split())}", file=sys.stderr)
                    continue
                outs[method] = (full, out_a, out_b, time.perf_counter() - t0)
            if cfile is not None:
                cfile.parent.mkdir(parents=True, exist_ok=True)
                keep = {n: fb[n] for n in ("color", "color_a", "color_b", "color_a_var",
                                           "color_b_var")}  # fmt: skip
                torch.save({"fb": keep, "ref": ref, "ref_var": ref_var, "outs": outs}, cfile)
            outs = {m: outs[m] for m in methods if m in outs}
            variants = variant_estimates(fb, outs, ref)
            for method, (full, out_a, out_b, seconds) in outs.items():
                norm = matched_normaliser(full, fb["color"])  # what --estimate-error does
                est = estimate_from_outputs(
                    out_a, out_b, fb, output=full, normaliser=norm, block=block
                )
                est_mean = estimate_from_outputs(out_a, out_b, fb)
                shared = variants[method].get("_shared")  # what eval without --ref divides by
                est_shared = (
                    estimate_from_outputs(
                        out_a, out_b, fb, output=full, normaliser=shared, block=block
                    )
                    if shared is not None
                    else None
                )
                true, true_corr = _relmse_terms(full, ref, ref_var)
                mean_true, mean_corr = _relmse_terms((out_a + out_b) / 2, ref, ref_var)
                rec = {
                    "image": img["id"], "spp": level, "method": method,
                    "estimate": est.reported, "estimate_se": est.relmse_se,
                    "estimate_upper": est.upper is not None,
                    "estimate_halves_mean": est_mean.relmse,
                    **{f"estimate_{k}": v for k, v in variants[method].items() if k[0] != "_"},
                    "estimate_shared_med_matched_se": est_shared.relmse_se
                    if est_shared else float("nan"),
                    **({"estimate_shared": est_shared.reported,
                        "estimate_shared_se": est_shared.relmse_se,
                        "estimate_shared_upper": est_shared.upper is not None}
                       if est_shared else {}),
                    "true": true, "true_corrected": true_corr,
                    "halves_mean_true": mean_true, "halves_mean_corrected": mean_corr,
                    "seconds": round(seconds, 3),
                }  # fmt: skip
                records.append(rec)
                done[f"{img['id']}/{level}/{method}"] = rec
                print(
                    f"{img['id']}/{level}/{method}: estimate {est.reported:.4g} "
                    f"± {est.relmse_se:.2g} (shared {rec.get('estimate_shared_med_matched', 0):.4g}, oracle "
                    f"{rec['estimate_oracle']:.4g}), true {true:.4g} (corrected {true_corr:.4g})",
                    file=sys.stderr,
                )
    return records


def variant_estimates(fb, outs: dict, ref) -> dict[str, dict]:
    """Per method (``outs``: method -> (full, out_a, out_b, seconds)), the relMSE estimate
    of each variant. The squared-error form: ``½(A − B)²`` for the common term (what the
    library uses), or with ``avg_``, its mean with the halves' variance buffers; with
    ``wins_``, the product of the two halves' residuals clipped at ±9 √(v_A v_B) (a robust
    variant, biased: ``synthetic`` measures how much). The normaliser: ``own`` the method's
    output (what ``--estimate-error`` wrote until the matched normaliser), ``matched`` its
    :func:`~mcdenoise.eval.estimate.matched_normaliser` (what it writes now), ``matched_r1``
    the same over 3×3, ``plus`` its one-sided form (energy only added back), ``max_box``
    ``max(output, box5(input))``; ``residual_``: plus ``(D(x) − x)² − (hm − x)²`` per pixel
    (``hm`` the mean of the filtered halves: a correction of the carry-over, exact only if
    ``D(x) − hm`` were uncorrelated with the input's noise); ``med3`` the pixelwise median of it and the two halves,
    ``shrunkK`` it moved towards the input by ``d²/(d² + K·v)`` (``d``: their difference,
    ``v``: the input's variance, 3×3 mean; issue 36: neither is kept);
    ``shared`` the torch (lower) median of the denoisers'
    outputs (last session's), ``shared_med`` the proper median
    (:func:`~mcdenoise.eval.estimate.pseudo_reference`), ``shared_matched`` that matched
    (what ``mcdenoise eval`` without ``--ref`` uses for several outputs), ``shared_*`` as for
    the output; ``oracle`` the reference (a diagnostic). ``_shared``: the tensor of
    ``shared_med_matched`` (``None`` without a denoiser)."""
    import torch

    from mcdenoise.eval.estimate import matched_normaliser, pseudo_reference, squared_error
    from mcdenoise.filters.box import box_mean
    from mcdenoise.losses import RELMSE_EPS

    a, b = fb["color_a"].double(), fb["color_b"].double()
    va, vb = fb["color_a_var"].double(), fb["color_b_var"].double()
    x = fb["color"].double()
    denoised = [o[0].double() for m, o in outs.items() if m != "noisy"]
    box2 = lambda t: box_mean(t[None], 2)[0]  # noqa: E731

    def med3(img):  # the pixelwise median of the image and the two halves
        return torch.stack([img, a, b]).median(0).values

    vx = box_mean(((va + vb) / 4)[None], 1)[0]  # the input's variance of the mean, 3×3

    def shrunk(img, k):  # towards the input where they differ by more than its noise explains
        d2 = (x - img).square()
        return img + (x - img) * d2 / (d2 + k * vx + 1e-12)

    def normalisers(img, tag):
        m = matched_normaliser(img, x)
        return {
            tag: img,
            f"{tag}_med3": med3(img),
            f"{tag}_matched_med3": med3(m),
            f"{tag}_shrunk9": shrunk(img, 9),
            f"{tag}_matched_shrunk9": shrunk(m, 9),
            f"{tag}_matched_shrunk4": shrunk(m, 4),
            f"{tag}_matched_shrunk25": shrunk(m, 25),
            f"{tag}_matched": matched_normaliser(img, x),
            f"{tag}_matched_r1": matched_normaliser(img, x, 1),
            f"{tag}_plus": img + box2(x - img).clamp_min(0),
            f"{tag}_max_box": torch.maximum(img, box2(x)),
        }

    shared: dict = {}
    if denoised:
        shared = normalisers(pseudo_reference(denoised), "shared_med")
        shared["shared"] = torch.stack(denoised).median(0).values
    res: dict[str, dict[str, float]] = {}
    for method, (full, out_a, out_b, _s) in outs.items():
        full, out_a, out_b = full.double(), out_a.double(), out_b.double()
        sq = squared_error(out_a, out_b, a, b)
        sq_avg = sq + 0.25 * (a - b).square() - 0.25 * (va + vb)
        prod = (a - out_a) * (b - out_b)  # sq = ¼(D_A − D_B)² + this product (docs)
        cap = 9 * (va * vb).sqrt()
        sq_wins = sq - prod + torch.maximum(torch.minimum(prod, cap), -cap)
        # the carry-over corrected by the residual energies against the input (issue 36)
        sq_res = sq + (full - x).square() - ((out_a + out_b) / 2 - x).square()
        norms = {**normalisers(full, "own"), **shared, "oracle": ref}
        r = {}
        forms = (("", sq), ("avg_", sq_avg), ("wins_", sq_wins), ("residual_", sq_res))
        for form, e in forms:
            for name, d in norms.items():
                if form and name not in ("own_matched", "shared_med_matched", "oracle"):
                    continue
                r[form + name] = max(float((e / (d.square() + RELMSE_EPS)).mean()), 0.0)
        r["_shared"] = shared.get("shared_med_matched")
        res[method] = r
    return res


def _spearman(x: list[float], y: list[float]) -> float:
    import numpy as np
    from scipy.stats import spearmanr

    if len(x) < 2:
        return float("nan")
    return float(spearmanr(np.asarray(x), np.asarray(y)).statistic)


def analyse(records: list[dict], truth: str = "true_corrected", estimate: str = "estimate") -> dict:
    """Per level: the share within :data:`FACTOR`, mean Spearman ρ over images; per method:
    geometric means of estimate/truth and of the carry-over."""
    import math
    from collections import defaultdict

    out: dict = {"truth": truth, "estimate": estimate, "levels": {}, "methods": {}}
    by_level: dict = defaultdict(list)
    for r in records:
        by_level[r["spp"]].append(r)
    for level, rs in sorted(by_level.items()):
        ok = [
            r[truth] > 0 and r[estimate] > 0 and 1 / FACTOR <= r[estimate] / r[truth] <= FACTOR
            for r in rs
        ]
        per_image: dict = defaultdict(list)
        for r in rs:
            per_image[r["image"]].append(r)
        rhos = [
            _spearman([r[estimate] for r in v], [r[truth] for r in v])
            for v in per_image.values()
            if len(v) > 2
        ]
        rhos = [x for x in rhos if not math.isnan(x)]
        out["levels"][level] = {
            "pairs": len(rs),
            "within_factor": sum(ok) / len(ok),
            "zeros": sum(r[estimate] == 0 for r in rs),
            "upper_bounds": sum(bool(r.get(estimate + "_upper")) for r in rs),
            "spearman_mean": sum(rhos) / len(rhos) if rhos else float("nan"),
            # the truth within ±2 reported standard errors (where the estimate has one)
            "within_2se": sum(abs(r[estimate] - r[truth]) <= 2 * r[estimate + "_se"] for r in rs)
            / len(rs)
            if all(estimate + "_se" in r for r in rs)
            else float("nan"),
            "images": len(rhos),
        }
    by_method: dict = defaultdict(list)
    for r in records:
        by_method[(r["method"], r["spp"])].append(r)
    for (method, level), rs in sorted(by_method.items()):
        pos = [r for r in rs if r[truth] > 0 and r[estimate] > 0]
        gm = lambda v: math.exp(sum(math.log(x) for x in v) / len(v)) if v else float("nan")  # noqa: E731
        out["methods"][f"{method}@{level}"] = {
            "estimate_over_truth": gm([r[estimate] / r[truth] for r in pos]),
            "full_over_halves_mean": gm(
                [
                    r["true_corrected"] / r["halves_mean_corrected"]
                    for r in rs
                    if r["true_corrected"] > 0 and r["halves_mean_corrected"] > 0
                ]
            ),
        }
    return out


def _print_analysis(a: dict, brief: bool = False) -> None:
    if brief:  # one line: within-factor and rho per level
        cells = "  ".join(
            f"{level}: {v['within_factor']:.3f} {v['spearman_mean']:.3f}"
            for level, v in a["levels"].items()
        )
        zeros = sum(v["zeros"] for v in a["levels"].values())
        print(f"{a['estimate']:26s} vs {a['truth']:16s} {cells}  zeros {zeros}")
        return
    print(f"estimate '{a['estimate']}' against truth '{a['truth']}':")
    for level, v in a["levels"].items():
        print(
            f"  {level:>3} spp: within {FACTOR}x {v['within_factor']:.3f} of {v['pairs']} pairs; "
            f"Spearman rho {v['spearman_mean']:.3f} (mean of {v['images']} images); "
            f"truth within 2 SE {v['within_2se']:.2f}; exact zeros {v['zeros']}, "
            f"upper bounds {v['upper_bounds']}"
        )
    for k, v in a["methods"].items():
        print(
            f"    {k:22s} estimate/truth {v['estimate_over_truth']:.3f}  "
            f"full/halves-mean {v['full_over_halves_mean']:.3f}"
        )


def heldout(args: argparse.Namespace) -> int:
    import json

    done: dict = {}
    if args.from_json:
        records = [r for f in args.from_json for r in json.loads(Path(f).read_text())["records"]]
    else:
        if args.json and Path(args.json).exists():
            for r in json.loads(Path(args.json).read_text())["records"]:
                done[f"{r['image']}/{r['spp']}/{r['method']}"] = r
        import torch

        torch.set_num_threads(args.threads)
        spp = [int(v) for v in args.spp.split(",")]
        records = heldout_records(
            Path(args.data),
            spp,
            args.methods.split(","),
            done,
            ref_dir=Path(args.ref_dir) if args.ref_dir else None,
            images=args.images.split(",") if args.images else None,
            cache=Path(args.cache) if args.cache else None,
            block=args.block,
            share_guides=args.share_guides,
            half_noise=args.half_noise,
        )
        if args.json:
            Path(args.json).write_text(json.dumps({"records": records}, indent=1))
    have = set.intersection(*(set(r) for r in records)) if records else set()
    pairs = [("true_corrected", "estimate"), ("true", "estimate")]
    pairs += [("true_corrected", k) for k in sorted(have) if k.startswith("estimate_")
              and not k.endswith(("_se", "_upper")) and k != "estimate_halves_mean"]  # fmt: skip
    pairs += [("halves_mean_corrected", "estimate_halves_mean")]
    # the ceiling (issue 36): estimates against the error of the mean of the filtered halves,
    # which they are unbiased for, and that error itself against the full output's
    pairs += [
        ("halves_mean_corrected", k) for k in ("estimate_oracle", "estimate_shared_med_matched")
    ]
    pairs += [("true_corrected", "halves_mean_corrected")]
    for truth, est in pairs:
        if est in have and (not args.only or est in args.only.split(",")):
            _print_analysis(analyse(records, truth, est), brief=args.brief)
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    rc = sub.add_parser("render-cost", help="extra render time of --halves")
    rc.add_argument("--scenes", nargs="+", default=list(CURATED))
    rc.add_argument("--reps", type=int, default=3)
    rc.add_argument("--res", type=int, default=128)
    rc.add_argument("--spp", default="4,16,64")
    rc.add_argument("--seed", type=int, default=0)
    rc.add_argument("--threads", type=int, default=1)
    rc.add_argument("--variant", default="llvm_ad_rgb")
    sy = sub.add_parser("synthetic", help="bias and per-block ranking on synthetic noise")
    sy.add_argument("--noises", nargs="+", default=list(NOISES))
    sy.add_argument("--trials", type=int, default=64)
    sy.add_argument("--size", type=int, default=128)
    sy.add_argument("--spp", type=int, default=8)
    sy.add_argument("--block", type=int, default=16)
    fs = sub.add_parser("file-size", help="file size with every guide halved, colour only, none")
    fs.add_argument("data", nargs="+")
    sg = sub.add_parser("shared-guides", help="bias from guides shared by both halves")
    sg.add_argument("--trials", type=int, default=64)
    sg.add_argument("--size", type=int, default=128)
    sg.add_argument("--spp", type=int, default=4)
    ho = sub.add_parser("heldout", help="estimate vs truth on held-out renders with halves")
    ho.add_argument("--data", default=str(HELDOUT))
    ho.add_argument("--spp", default="4,16,64")
    ho.add_argument("--methods", default=",".join(METHODS))
    ho.add_argument("--threads", type=int, default=1)
    ho.add_argument(
        "--ref-dir",
        default=None,
        help="references as DIR/<id>.exr (the same ids and seeds rendered with a reference "
        "elsewhere, e.g. data/generated/heldout/ref for a --halves render of its scenes)",
    )
    ho.add_argument("--images", default=None, help="only these image ids (comma-separated)")
    ho.add_argument("--json", default=None, help="write (and resume from) every record here")
    ho.add_argument("--cache", default=None, help="keep the outputs here (.pt per image, level)")
    ho.add_argument("--brief", action="store_true", help="one line per estimator")
    ho.add_argument("--block", type=int, default=16, help="block side of the standard errors")
    ho.add_argument("--only", default=None, help="only these estimators (comma-separated)")
    ho.add_argument(
        "--half-noise",
        choices=("half", "full"),
        default="half",
        help="full: each half's variances halved and its spp set to the full count",
    )
    ho.add_argument(
        "--share-guides",
        action="store_true",
        help="drop the feature halves first: both halves share the guides (before issue 36)",
    )
    ho.add_argument(
        "--from-json", nargs="+", default=None, help="only analyse the records of these files"
    )
    args = ap.parse_args(argv)
    cmds = {
        "render-cost": render_cost,
        "synthetic": synthetic,
        "shared-guides": shared_guides,
        "file-size": file_size,
        "heldout": heldout,
    }
    return cmds[args.cmd](args)


if __name__ == "__main__":
    sys.exit(main())

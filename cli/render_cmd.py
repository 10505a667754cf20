"""``mcdenoise render``: click wiring for :func:`mcdenoise.render.generate.render_dataset`."""

from __future__ import annotations

from pathlib import Path

import click
from mcdenoise_cli.options import progress_option, threads_option


@click.command("render")
@click.argument("specs", nargs=-1, type=click.Path())
@click.option(
    "--random",
    "random_count",
    type=int,
    default=None,
    metavar="N",
    help="Also render N procedural scenes (seeded by --seed).",
)
@click.option(
    "--seed",
    type=int,
    default=0,
    show_default=True,
    help="Base seed: of the procedural scenes and of every image's sampler seeds.",
)
@click.option(
    "-o", "--out", required=True, type=click.Path(), help="Output folder (created if missing)."
)
@click.option("--res", default="256", show_default=True, help="Image size: N or WxH pixels.")
@click.option(
    "--spp",
    default="4,16,64",
    show_default=True,
    help="Noisy spp levels, increasing; rendered progressively (16 reuses 4's samples).",
)
@click.option("--ref-spp", type=int, default=4096, show_default=True, help="Reference spp.")
@click.option(
    "--variant",
    default="auto",
    show_default=True,
    metavar="auto|scalar_rgb|llvm_ad_rgb|cuda_ad_rgb",
    help="Mitsuba variant; auto: cuda_ad_rgb with a GPU, else llvm_ad_rgb if it works, else "
    "scalar_rgb.",
)
@click.option(
    "--shard",
    default="1/1",
    show_default=True,
    metavar="I/N",
    help="Render only images with index = I-1 (mod N); shards are numbered 1..N.",
)
@click.option(
    "--pass-spp",
    type=int,
    default=128,
    show_default=True,
    help="Most samples per pixel of one render call (bounds memory).",
)
@click.option(
    "--compression",
    default="zip",
    show_default=True,
    type=click.Choice(["none", "zip", "zips", "piz", "rle"]),
    help="EXR compression (lossless only).",
)
@click.option(
    "--frames",
    type=int,
    default=None,
    metavar="N",
    help="Render every scene as a sequence of N >= 2 frames (its [animation] camera path, "
    "else a 1°-per-frame orbit) with motion vectors: OUT/<id>/frame_0000.exr, "
    "OUT/<id>/ref/frame_0000.exr, ...",
)
@click.option(
    "--halves/--no-halves",
    default=True,
    show_default=True,
    help="Also write per level two independent half-sample buffers color_a/color_b (each "
    "the mean of spp/2 samples from disjoint sample streams; colour = their mean), with "
    "their variances, and feature halves with depth of field (docs/rendering.md#halves).",
)
@click.option(
    "--samples-out",
    type=click.Path(file_okay=False),
    default=None,
    metavar="DIR",
    help="Afterwards also write every image in the layout of data/samples: DIR/<id>_spp<n>.exr "
    "per level (colour float32, features half) and DIR/ref/<id>.exr (colour only).",
)
@click.option(
    "--layout",
    type=click.Choice(["mcdenoise", "oidn"]),
    default="mcdenoise",
    show_default=True,
    help="oidn: afterwards also write OUT/oidn/ in the training layout of OIDN's toolkit "
    "(<id>_0004spp.hdr.exr, .alb.exr, .nrm.exr, <id>_ref.hdr.exr; one feature per file).",
)
@threads_option(render=True)
@progress_option
def render(
    specs,
    random_count,
    seed,
    out,
    res,
    spp,
    ref_spp,
    variant,
    shard,
    pass_spp,
    compression,
    frames,
    halves,
    samples_out,
    layout,
    progress,
):
    """Render a denoising data set with Mitsuba 3 from scene SPECS (TOML files or folders of
    them) and/or --random N procedural scenes.

    \b
    Per image: OUT/<id>.exr (one part per spp level: spp4, spp16, ...; colour, features and
    their variances) and OUT/ref/<id>.exr (the reference); OUT/manifest.json records specs,
    seeds, the Mitsuba variant and the render seconds. Re-running skips finished images;
    --shard I/N splits the work between jobs writing into one folder. With --frames N, per
    scene the folder OUT/<id>/ holds frame_0000.exr ... (the same buffers plus `motion`) and
    ref/frame_0000.exr ...; sequences are sharded whole and resumed frame by frame.
    """
    from mcdenoise_cli.parsing import parse_res, parse_shard, parse_spp  # lazy: start-up of the CLI

    from mcdenoise.denoise_files import check_output_folder  # lazy: start-up of the CLI
    from mcdenoise.render.config import RenderConfig  # lazy: start-up of the CLI
    from mcdenoise.render.generate import render_dataset  # lazy: start-up of the CLI

    check_output_folder(out, "-o")
    if layout == "oidn" and frames is not None:
        raise click.UsageError("--layout oidn is for still images, not --frames")
    if samples_out is not None:
        check_output_folder(samples_out, "--samples-out")
    width, height = parse_res(res)
    config = RenderConfig(
        out=Path(out),
        width=width,
        height=height,
        spp=parse_spp(spp),
        ref_spp=ref_spp,
        variant=variant,
        shard=parse_shard(shard),
        pass_spp=pass_spp,
        seed=seed,
        compression=compression,
        progress="auto" if progress is None else ("bar" if progress else "off"),
        frames=frames,
        halves=halves,
    )
    result = render_dataset(specs, config, random=random_count, samples_out=samples_out)
    i, n = config.shard
    where = f" (shard {i}/{n})" if n > 1 else ""
    how = f" with {result.variant}" if result.variant else ""
    what = "image(s)" if frames is None else f"sequence(s) of {frames} frames"
    click.echo(
        f"rendered {len(result.rendered)}, skipped {len(result.skipped)} already finished, "
        f"of {result.shard_jobs} {what}{where}{how} in {result.seconds:.1f} s; "
        f"manifest: {result.manifest}"
    )
    if samples_out is not None:
        click.echo(f"samples layout: {len(result.exported)} file(s) in {samples_out}")
    if layout == "oidn":
        from mcdenoise.io.oidn_layout import write_oidn_layout  # lazy: start-up of the CLI

        written = write_oidn_layout(config.out, config.out / "oidn")
        click.echo(f"oidn layout: {len(written)} file(s) in {config.out / 'oidn'}")

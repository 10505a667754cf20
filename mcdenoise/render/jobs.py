"""What a render run renders: image jobs, their ids and seeds, and the passes of each level.

Jobs
    One :class:`ImageJob` per image (one scene spec, one seed): curated specs
    (:func:`jobs_from_specs`, ids from the spec names, made file-name safe and unique) and/or
    procedural scenes (:func:`jobs_from_random`, ids ``random_s<seed>_<k>``). An image's seed
    is a hash of the run's base seed and its id (:func:`image_seed`), so it does not change
    when other images are added to or removed from the job list.
Progressive spp levels
    The requested levels (e.g. 4, 16, 64) are rendered as *increments* (4, then 12 more, then
    48 more) with distinct seeds, and each level pools the moments of every increment up to it:
    level 16 contains level 4's samples and costs only 12 more spp. Each level is still an
    unbiased Monte Carlo estimate (the mean of i.i.d. samples); levels of one image are *not*
    independent of each other (compare images, not levels of one image, when independence
    matters). An increment larger than ``pass_spp`` is split into passes of at most
    ``pass_spp`` samples (:func:`level_passes`; default
    :data:`~mcdenoise.render.config.DEFAULT_PASS_SPP` = 128 for every variant: the JIT
    variants hold a whole pass in memory, about ``width * height * pass_spp`` samples; scalar
    memory does not grow with spp, and the same default keeps seeds comparable).
Halves (``RenderConfig.halves``)
    Every increment is rendered as two sets of passes, one per half (:func:`half_level_passes`):
    half A holds ``ceil(L / 2)`` and half B ``floor(L / 2)`` of the ``L`` samples of a level, so
    at every even level both hold ``L / 2``. Each render call (pass) gets the next noisy seed,
    whichever half it belongs to, so the two halves are disjoint sample streams.
Reference
    ``ref_spp`` samples in passes of at most ``pass_spp``, with seeds disjoint from the noisy
    ones: noisy pass ``k`` of an image with seed ``s`` uses sampler seed ``s + 2k``
    (:func:`noisy_seed`), reference pass ``k`` uses ``s + 2k + 1`` (:func:`reference_seed`).
Sequences
    Frame ``f`` of a sequence seeded ``s`` is rendered like a still image with its own image
    seed :func:`frame_seed` ``(s, f)``, so the noise of consecutive frames is independent.
"""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass

from mcdenoise.render.config import RenderError, check_spp_levels
from mcdenoise.render.scene_spec import SceneSpec, load_spec

_SEED_MOD = 2**31


@dataclass(frozen=True)
class ImageJob:
    """One image to render: its position in the job list, file stem, spec and seed."""

    index: int
    id: str
    spec: SceneSpec
    seed: int
    base_seed: int = 0


def image_seed(base_seed: int, image_id: str) -> int:
    """The seed of image ``image_id``: a hash of the base seed and the id, in ``[0, 2**31)``
    (stable when other images are added to or removed from the job list)."""
    digest = hashlib.blake2b(f"{base_seed}/{image_id}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "little") % _SEED_MOD


def _safe_id(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "scene"


def _unique_ids(names: Sequence[str], taken: set[str] | None = None) -> list[str]:
    seen = set(taken or ())
    out = []
    for name in names:
        base = _safe_id(name)
        candidate, k = base, 2
        while candidate in seen:
            candidate, k = f"{base}_{k}", k + 1
        seen.add(candidate)
        out.append(candidate)
    return out


def jobs_from_specs(specs: Sequence[SceneSpec], seed: int = 0, start: int = 0) -> list[ImageJob]:
    """One job per spec, ids from the spec names (file-name safe, made unique), indices from
    ``start``."""
    ids = _unique_ids([s.name for s in specs])
    return [
        ImageJob(start + k, i, s, image_seed(seed, i), seed)
        for k, (i, s) in enumerate(zip(ids, specs))
    ]


def jobs_from_random(
    count: int, seed: int = 0, start: int = 0, taken: Sequence[str] = ()
) -> list[ImageJob]:
    """``count`` procedural scenes ``random_spec(seed, k)``, ids ``random_s<seed>_<k>``."""
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise RenderError(f"--random must be an integer >= 1, got {count!r}")
    try:
        from mcdenoise.render.random_scenes import (  # lazy: optional, see except
            random_spec,
        )
    except ImportError:
        raise RenderError(
            "--random needs mcdenoise.render.random_scenes, which this installation lacks"
        ) from None
    ids = _unique_ids([f"random_s{seed}_{k:05d}" for k in range(count)], set(taken))
    return [
        ImageJob(start + k, ids[k], random_spec(seed, k), image_seed(seed, ids[k]), seed)
        for k in range(count)
    ]


def make_jobs(
    spec_files: Sequence[str | os.PathLike[str]], *, random: int | None = None, seed: int = 0
) -> list[ImageJob]:
    """The jobs of one run: one per spec file (loaded and validated, in order), then ``random``
    procedural scenes (``None``: none), ids unique across both, seeded by ``seed``.

    Raises:
        SpecError: a spec file that cannot be read or is invalid.
        RenderError: ``random`` is not an integer >= 1, or the generator is missing.
    """

    jobs = jobs_from_specs([load_spec(f) for f in spec_files], seed=seed)
    if random is not None:
        jobs += jobs_from_random(random, seed, start=len(jobs), taken=[j.id for j in jobs])
    return jobs


def split_passes(spp: int, pass_spp: int) -> list[int]:
    """Pass sizes that sum to ``spp``, each at most ``pass_spp``.

    >>> split_passes(300, 128)
    [128, 128, 44]
    """
    full, rest = divmod(spp, pass_spp)
    return [pass_spp] * full + ([rest] if rest else [])


def level_passes(levels: Sequence[int], pass_spp: int) -> list[list[int]]:
    """For each level, the pass sizes of its increment over the previous level.

    >>> level_passes([4, 16, 300], 128)
    [[4], [12], [128, 128, 28]]
    """
    out, prev = [], 0
    for level in check_spp_levels(levels):
        out.append(split_passes(level - prev, pass_spp))
        prev = level
    return out


def half_level_passes(levels: Sequence[int], pass_spp: int) -> list[tuple[list[int], list[int]]]:
    """For each level, the pass sizes of its increment in half A and in half B.

    Half A holds ``ceil(L/2)`` samples of level ``L``, half B ``floor(L/2)``; an empty list
    means the half gets no samples in that increment.

    >>> half_level_passes([1, 4, 16, 300], 128)
    [([1], []), ([1], [2]), ([6], [6]), ([128, 14], [128, 14])]
    """
    out, prev_a, prev_b = [], 0, 0
    for level in check_spp_levels(levels):
        a, b = (level + 1) // 2, level // 2
        out.append((split_passes(a - prev_a, pass_spp), split_passes(b - prev_b, pass_spp)))
        prev_a, prev_b = a, b
    return out


def noisy_seed(seed: int, k: int) -> int:
    """Sampler seed of noisy pass ``k`` (counted over all levels) of an image seeded ``seed``."""
    return seed + 2 * k


def reference_seed(seed: int, k: int) -> int:
    """Sampler seed of reference pass ``k``; never equal to a noisy pass seed of the image."""
    return seed + 2 * k + 1


def frame_seed(seed: int, frame: int) -> int:
    """Image seed of frame ``frame`` of a sequence seeded ``seed``: a hash, so the pass seeds
    (``+ 2k``, ``+ 2k + 1``) of different frames do not collide in practice."""
    return image_seed(seed, f"frame_{frame:04d}")


def level_part(spp: int) -> str:
    """Part name of a level in the noisy file: ``spp16``."""
    return f"spp{spp}"

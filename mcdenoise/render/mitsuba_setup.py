"""Mitsuba itself: which variant works on this machine (probed in a subprocess, so a variant that
crashes cannot take the caller down), the imported module, and loading a scene dict with a
bounded number of threads. :mod:`mcdenoise.render.scenes` builds the dicts.
"""

from __future__ import annotations

import functools
import subprocess
import sys
from typing import Any

from mcdenoise.errors import InputError
from mcdenoise.render.integrators import register_integrators

#: Variants :func:`ensure_variant` accepts, and the order ``auto`` tries them in.
VARIANTS: tuple[str, ...] = ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")


# --------------------------------------------------------------------------------------------
# Variant
# --------------------------------------------------------------------------------------------
_PROBE = """
import mitsuba as mi
mi.set_variant({variant!r})
scene = mi.load_dict({{"type": "scene", "integrator": {{"type": "path"}},
    "sensor": {{"type": "perspective",
    "film": {{"type": "hdrfilm", "width": 4, "height": 4}}}},
    "s": {{"type": "sphere", "emitter": {{"type": "area"}}}}}})
img = mi.render(scene, spp=2)
assert img.shape == (4, 4, 3)
"""


@functools.cache
def variant_works(variant: str, timeout: float = 180.0) -> bool:
    """True when Mitsuba ``variant`` renders a tiny scene here (cached per process).

    Probed in a child process: a JIT variant with a broken LLVM (Debian's LLVM 14/15) aborts
    the interpreter instead of raising, and ``cuda_ad_rgb`` needs a working GPU driver.
    """
    try:
        proc = subprocess.run(
            [sys.executable, "-c", _PROBE.format(variant=variant)],
            capture_output=True,
            timeout=timeout,
            check=False,
        )
    except (OSError, subprocess.TimeoutExpired):
        return False
    return proc.returncode == 0


def ensure_variant(requested: str = "auto") -> str:
    """Set the Mitsuba variant, register ``mcd_ao``/``mcd_path``, and return the variant.

    ``auto``: ``cuda_ad_rgb`` if a GPU works, else ``llvm_ad_rgb`` if it works (it needs
    ``libllvm19``), else ``scalar_rgb``. A named variant (one of :data:`VARIANTS`) is checked
    the same way, so a broken JIT gives this error instead of aborting the interpreter.

    Raises:
        InputError: unknown variant, not compiled into this Mitsuba, or not working here.
    """
    import mitsuba as mi  # lazy: Mitsuba is optional and slow to import

    if requested == "auto":
        candidates = [v for v in VARIANTS if v in mi.variants()]
        if mi.variant() in candidates[:1]:  # the best one is already set
            chosen = str(mi.variant())
        else:
            chosen = next((v for v in candidates if _works(v)), "")
        if not chosen:
            raise InputError(f"none of the Mitsuba variants {', '.join(VARIANTS)} works here")
    else:
        if requested not in VARIANTS:
            raise InputError(
                f"unknown Mitsuba variant {requested!r} (use auto, {', '.join(VARIANTS)})"
            )
        if requested not in mi.variants():
            raise InputError(
                f"Mitsuba variant {requested!r} is not in this build "
                f"(it has {', '.join(mi.variants())})"
            )
        if not _works(requested):
            hint = " (is Debian's libllvm19 installed?)" if requested.startswith("llvm") else ""
            raise InputError(f"Mitsuba variant {requested!r} does not work here{hint}")
        chosen = requested
    if mi.variant() != chosen:
        mi.set_variant(chosen)
    register_integrators()
    return chosen


def _works(variant: str) -> bool:
    # scalar variants cannot abort the interpreter: no probe needed.
    return variant.startswith("scalar") or variant_works(variant)


def _mi() -> Any:
    import mitsuba as mi  # lazy: Mitsuba is optional and slow to import

    if mi.variant() is None:
        raise InputError("no Mitsuba variant is set: call ensure_variant() first")
    return mi


#: Dr.Jit worker threads while Mitsuba loads a scene. Mitsuba 3.9.1 (``llvm_ad_rgb``) never
#: returns from loading an ``envmap`` with a file when Dr.Jit has ONE worker thread (all
#: threads wait on a futex: what ``--threads 1``, or ``auto`` on a busy machine, used to do to
#: every scene with an environment map file); with two it loads at once. Rendering itself is
#: fine with one thread.
LOAD_THREADS = 2


def load_scene(d: dict[str, Any]) -> Any:
    """``mi.load_dict(d)`` with at least :data:`LOAD_THREADS` Dr.Jit threads during the load
    (the caller's thread count is restored afterwards)."""
    import drjit as dr  # lazy: Mitsuba is optional and slow to import

    mi = _mi()
    before = int(dr.thread_count())
    if before < LOAD_THREADS:
        dr.set_thread_count(LOAD_THREADS)
    try:
        return mi.load_dict(d)
    finally:
        if before < LOAD_THREADS:
            dr.set_thread_count(before)

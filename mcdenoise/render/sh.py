"""Environment lighting from real spherical-harmonic (SH) coefficients, as a Mitsuba ``envmap``.

Convention (the one of Liu et al., "Real-Time Lighting Estimation for AR via Differentiable
Screen-Space Rendering", and of Ramamoorthi & Hanrahan's irradiance environment maps):

* **Basis.** Real, *orthonormal* SH on the unit sphere, ``∫ Y_i Y_j dω = δ_ij``, **without**
  the Condon–Shortley phase::

      Y_l^0  = K_l^0 P_l^0(cos θ)
      Y_l^m  = √2 K_l^m cos(m φ)  P_l^m(cos θ)     (m > 0)
      Y_l^m  = √2 K_l^|m| sin(|m| φ) P_l^|m|(cos θ) (m < 0)
      K_l^m  = √((2l + 1) / (4π) · (l − m)! / (l + m)!)

  with P_l^m the associated Legendre functions without the (−1)^m factor. So
  ``Y_0^0 = 0.282095``, ``(Y_1^-1, Y_1^0, Y_1^1) = 0.488603 · (y, z, x)``,
  ``Y_2^-2 = 1.092548 xy`` … (tested against these closed forms).
* **Layout.** Coefficient ``(l, m)`` sits at row ``l (l + 1) + m`` of a ``((order+1)², C)``
  array: ``(0,0), (1,−1), (1,0), (1,1), (2,−2), …``. Order 5 = 36 rows; colour coefficients are
  ``(36, 3)`` linear-RGB (Rec. 709 primaries) radiance: ``L(ω) = Σ_i c_i Y_i(ω)``.
* **Axes.** θ is measured from the SH frame's **+z axis, which is "up"**; φ from +x towards +y.
  The SH frame maps to Mitsuba world space (``envmap``'s default +Y up) by the usual z-up →
  y-up rotation (as Blender → glTF): ``x_sh = X``, ``y_sh = −Z``, ``z_sh = Y``. An SH ``Y_1^0``
  term therefore brightens the sky (+Y), ``Y_1^1`` the +X side and ``Y_1^-1`` the −Z side. Put a
  ``to_world`` transform on the returned emitter dict to rotate the lighting further.
* **Lat-long image.** The image follows Mitsuba's ``envmap`` parameterisation exactly: row ``i``
  of ``H`` samples polar angle ``θ = π i / (H − 1)`` from +Y (first row the north pole, last
  row the south pole), column ``j`` of ``W`` samples ``u = (j + ½) / W`` with world direction
  ``(sin θ sin 2πu, cos θ, −sin θ cos 2πu)``; Mitsuba interpolates bilinearly between these
  samples. Radiance below 0 (an SH truncation artefact) is clamped to 0; how much, is reported
  by :func:`sh_to_latlong_with_stats`.

All arrays are NumPy; directions are ``(N, 3)`` unit vectors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from mcdenoise.errors import InputError, McdenoiseError

#: Order of the AR-lighting paper's SH lighting: 5, i.e. (5 + 1)² = 36 coefficients.
PAPER_ORDER = 5


def num_coeffs(order: int) -> int:
    """Number of SH coefficients up to ``order`` (inclusive): ``(order + 1)²``."""
    _check_order(order)
    return (order + 1) ** 2


def sh_index(l: int, m: int) -> int:  # noqa: E741 - standard SH notation
    """Row of coefficient ``(l, m)``: ``l (l + 1) + m``; requires ``|m| <= l``.

    >>> sh_index(0, 0), sh_index(1, -1), sh_index(1, 1), sh_index(5, 5)
    (0, 1, 3, 35)
    """
    if l < 0 or abs(m) > l:
        raise InputError(f"SH index needs l >= 0 and |m| <= l, got l={l}, m={m}")
    return l * (l + 1) + m


def order_of(coeffs: np.ndarray) -> int:
    """SH order of a ``((order+1)², C)`` coefficient array; error if the row count is not a square."""
    n = int(np.shape(coeffs)[0]) if np.ndim(coeffs) >= 1 else 0
    order = math.isqrt(n) - 1
    if n == 0 or (order + 1) ** 2 != n:
        raise InputError(f"SH coefficients need (order+1)^2 rows (1, 4, 9, ..., 36), got {n}")
    return order


def _check_order(order: int) -> None:
    if isinstance(order, bool) or not isinstance(order, int | np.integer) or order < 0:
        raise InputError(f"SH order must be an integer >= 0, got {order!r}")


def _check_coeffs(coeffs: Any, channels: int | None = 3) -> np.ndarray:
    c = np.asarray(coeffs, dtype=np.float64)
    if c.ndim != 2 or (channels is not None and c.shape[1] != channels):
        want = f"(n, {channels})" if channels is not None else "(n, C)"
        raise InputError(f"SH coefficients must have shape {want}, got {c.shape}")
    order_of(c)
    if not np.isfinite(c).all():
        raise InputError("SH coefficients contain NaN or Inf")
    return c


def _check_dirs(dirs: Any) -> np.ndarray:
    d = np.asarray(dirs, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] != 3:
        raise InputError(f"directions must have shape (N, 3), got {d.shape}")
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    if not (np.isfinite(norm).all() and (norm > 0).all()):
        raise InputError("directions must be finite and non-zero")
    return d / norm


# --------------------------------------------------------------------------- frames


def world_to_sh_frame(dirs: np.ndarray) -> np.ndarray:
    """Mitsuba world directions (+Y up) → SH frame (+z up): ``(X, Y, Z) → (X, −Z, Y)``."""
    d = np.asarray(dirs, dtype=np.float64)
    return np.stack([d[..., 0], -d[..., 2], d[..., 1]], axis=-1)


def sh_frame_to_world(dirs: np.ndarray) -> np.ndarray:
    """SH frame (+z up) → Mitsuba world (+Y up): ``(x, y, z) → (x, z, −y)``."""
    d = np.asarray(dirs, dtype=np.float64)
    return np.stack([d[..., 0], d[..., 2], -d[..., 1]], axis=-1)


# --------------------------------------------------------------------------- basis


def sh_basis(order: int, dirs: np.ndarray) -> np.ndarray:
    """Real orthonormal SH basis (module convention) at directions in the **SH frame**.

    ``dirs``: ``(N, 3)`` directions (normalised here), +z up. Returns ``(N, (order+1)²)``
    float64, column ``l (l + 1) + m`` holding ``Y_l^m``. Associated Legendre functions come
    from the standard stable recurrences, so any order works (tested to 8).

    >>> np.round(sh_basis(1, np.array([[0.0, 0.0, 1.0]])), 6)
    array([[0.282095, 0.      , 0.488603, 0.      ]])
    """
    _check_order(order)
    d = _check_dirs(dirs)
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    n = d.shape[0]
    ct = np.clip(z, -1.0, 1.0)
    st = np.sqrt(np.maximum(0.0, 1.0 - ct * ct))
    phi = np.arctan2(y, x)
    out = np.empty((n, (order + 1) ** 2), dtype=np.float64)

    # P[l][m] for m <= l, no Condon-Shortley phase.
    p_mm = np.ones(n)  # P_0^0
    legendre: dict[tuple[int, int], np.ndarray] = {}
    for m in range(order + 1):
        if m > 0:
            p_mm = p_mm * (2 * m - 1) * st  # P_m^m = (2m-1)!! sin^m
        legendre[(m, m)] = p_mm
        if m + 1 <= order:
            legendre[(m + 1, m)] = (2 * m + 1) * ct * p_mm
        for l in range(m + 2, order + 1):  # noqa: E741
            legendre[(l, m)] = (
                (2 * l - 1) * ct * legendre[(l - 1, m)] - (l + m - 1) * legendre[(l - 2, m)]
            ) / (l - m)

    for l in range(order + 1):  # noqa: E741
        for m in range(0, l + 1):
            k = math.sqrt(
                (2 * l + 1) / (4 * math.pi) * math.factorial(l - m) / math.factorial(l + m)
            )
            p = legendre[(l, m)]
            if m == 0:
                out[:, sh_index(l, 0)] = k * p
            else:
                out[:, sh_index(l, m)] = math.sqrt(2.0) * k * np.cos(m * phi) * p
                out[:, sh_index(l, -m)] = math.sqrt(2.0) * k * np.sin(m * phi) * p
    return out


def eval_sh(coeffs: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Radiance ``Σ_i c_i Y_i(ω)`` at ``(N, 3)`` SH-frame directions: ``(N, C)`` float64, unclamped."""
    c = _check_coeffs(coeffs, channels=None)
    return sh_basis(order_of(c), dirs) @ c


def lambert_factors(order: int) -> np.ndarray:
    """Ramamoorthi–Hanrahan ``A_l`` (``(order+1,)``): clamped-cosine convolution per band.

    Irradiance ``E(n) = Σ_lm A_l c_lm Y_lm(n)``: ``A_0 = π``, ``A_1 = 2π/3``, ``A_2 = π/4``,
    0 for odd ``l > 1``.
    """
    _check_order(order)
    a = np.zeros(order + 1)
    for l in range(order + 1):  # noqa: E741
        if l == 0:
            a[l] = math.pi
        elif l == 1:
            a[l] = 2.0 * math.pi / 3.0
        elif l % 2 == 0:
            h = l // 2
            a[l] = (
                2.0
                * math.pi
                * (-1) ** (h - 1)
                / ((l + 2) * (l - 1))
                * math.factorial(l)
                / (2**l * math.factorial(h) ** 2)
            )
    return a


def sh_irradiance(coeffs: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Irradiance ``E(n) = ∫ L(ω) max(0, n·ω) dω`` for SH radiance ``coeffs`` (no clamping of
    negative radiance), at ``(N, 3)`` SH-frame normals: ``(N, C)``. A white Lambertian surface
    of albedo ρ then has outgoing radiance ``ρ E / π``."""
    c = _check_coeffs(coeffs, channels=None)
    order = order_of(c)
    a = lambert_factors(order)
    per_coeff = np.concatenate([np.full(2 * band + 1, a[band]) for band in range(order + 1)])
    return sh_basis(order, normals) @ (per_coeff[:, None] * c)


# --------------------------------------------------------------------------- lat-long


def _check_size(width: int, height: int) -> None:
    for name, v, lo in (("width", width, 2), ("height", height, 3)):
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < lo:
            raise InputError(f"lat-long {name} must be an integer >= {lo}, got {v!r}")


def latlong_directions(width: int, height: int) -> np.ndarray:
    """World directions (+Y up) of Mitsuba ``envmap`` texel samples: ``(H, W, 3)`` float64."""
    _check_size(width, height)
    theta = np.pi * np.arange(height) / (height - 1)
    u = (np.arange(width) + 0.5) / width
    phi = 2.0 * np.pi * u
    st = np.sin(theta)[:, None]
    return np.stack(
        [
            st * np.sin(phi)[None, :],
            np.broadcast_to(np.cos(theta)[:, None], (height, width)),
            -st * np.cos(phi)[None, :],
        ],
        axis=-1,
    )


def latlong_solid_angles(width: int, height: int) -> np.ndarray:
    """Quadrature weights (sr) of the texel samples, ``(H, W)``, summing to 4π.

    Row ``i`` owns the ring ``θ ∈ [θ_i − Δθ/2, θ_i + Δθ/2] ∩ [0, π]`` (the pole rows own
    polar caps), split evenly over the ``W`` columns; the weights are exact ring areas.
    """
    _check_size(width, height)
    dtheta = np.pi / (height - 1)
    theta = dtheta * np.arange(height)
    lo = np.clip(theta - dtheta / 2, 0, np.pi)
    hi = np.clip(theta + dtheta / 2, 0, np.pi)
    w = 2.0 * np.pi * (np.cos(lo) - np.cos(hi))
    return np.broadcast_to((w / width)[:, None], (height, width)).copy()


@dataclass(frozen=True)
class ClampStats:
    """How much negative radiance :func:`sh_to_latlong_with_stats` clamped to 0.

    ``texel_fraction``: share of texels with any channel < 0. ``solid_angle_fraction``: the
    same weighted by solid angle (share of the sphere). ``energy_fraction``: ∫ max(−L, 0) dω
    over ∫ |L| dω, summed over channels (0 when the radiance is non-negative everywhere).
    """

    texel_fraction: float
    solid_angle_fraction: float
    energy_fraction: float


def sh_to_latlong_with_stats(
    coeffs: np.ndarray, width: int, height: int
) -> tuple[np.ndarray, ClampStats]:
    """SH radiance → Mitsuba lat-long image ``(H, W, C)`` float32 (≥ 0), plus what was clamped."""
    c = _check_coeffs(coeffs, channels=None)
    dirs = latlong_directions(width, height).reshape(-1, 3)
    radiance = eval_sh(c, world_to_sh_frame(dirs)).reshape(height, width, c.shape[1])
    neg = radiance < 0
    sa = latlong_solid_angles(width, height)
    any_neg = neg.any(axis=-1)
    total = float((np.abs(radiance) * sa[..., None]).sum())
    clipped = float((np.where(neg, -radiance, 0.0) * sa[..., None]).sum())
    stats = ClampStats(
        texel_fraction=float(any_neg.mean()),
        solid_angle_fraction=float((any_neg * sa).sum() / sa.sum()),
        energy_fraction=clipped / total if total > 0 else 0.0,
    )
    return np.maximum(radiance, 0.0).astype(np.float32), stats


def sh_to_latlong(coeffs: np.ndarray, width: int, height: int) -> np.ndarray:
    """SH radiance ``coeffs`` (``(n, 3)``, e.g. ``(36, 3)``) → lat-long ``(H, W, 3)`` float32.

    Linear RGB radiance in Mitsuba's ``envmap`` layout (module docstring), negative values
    clamped to 0 (see :func:`sh_to_latlong_with_stats` for how much).
    """
    _check_coeffs(coeffs, channels=3)
    return sh_to_latlong_with_stats(coeffs, width, height)[0]


def project_latlong_to_sh(img: np.ndarray, order: int) -> np.ndarray:
    """Project a Mitsuba-layout lat-long image ``(H, W, C)`` (or ``(H, W)``) onto SH up to ``order``.

    Returns ``((order+1)², C)`` float64. Computed as the solid-angle-weighted least-squares fit
    ``argmin_c Σ_k w_k (f_k − Σ_i c_i Y_i(ω_k))²`` over the texel samples, i.e. the L2
    projection for the texel quadrature: it equals ``∫ f Y_i dω`` up to quadrature error and
    reproduces a band-limited image (order ≤ ``order``, not clamped) exactly.
    """
    _check_order(order)
    f = np.asarray(img, dtype=np.float64)
    squeeze = f.ndim == 2
    if squeeze:
        f = f[..., None]
    if f.ndim != 3:
        raise InputError(f"lat-long image must be (H, W) or (H, W, C), got shape {np.shape(img)}")
    height, width, channels = f.shape
    _check_size(width, height)
    if not np.isfinite(f).all():
        raise InputError("lat-long image contains NaN or Inf")
    if (order + 1) ** 2 > height * width:
        raise InputError(f"a {width}x{height} lat-long is too small for SH order {order}")
    dirs = world_to_sh_frame(latlong_directions(width, height).reshape(-1, 3))
    basis = sh_basis(order, dirs)  # (N, n)
    w = latlong_solid_angles(width, height).reshape(-1)
    sw = np.sqrt(w)[:, None]
    coeffs, *_ = np.linalg.lstsq(basis * sw, f.reshape(-1, channels) * sw, rcond=None)
    return coeffs


def sh_envmap_dict(coeffs: np.ndarray, scale: float = 1.0, width: int = 128) -> dict[str, Any]:
    """Mitsuba ``envmap`` emitter dict for SH radiance ``coeffs`` (``(n, 3)``), no temp files.

    The lat-long is ``width × (width/2 + 1)`` (square texels), built as an in-memory
    ``mi.Bitmap`` (float32 linear RGB); ``scale`` multiplies the radiance. Needs a Mitsuba
    variant to be set.
    """
    import mitsuba as mi  # lazy: Mitsuba is optional and slow to import

    if mi.variant() is None:
        raise McdenoiseError("sh_envmap_dict: set a Mitsuba variant first (mi.set_variant)")
    if not (isinstance(scale, int | float) and math.isfinite(scale) and scale >= 0):
        raise InputError(f"envmap scale must be a finite number >= 0, got {scale!r}")
    if isinstance(width, bool) or not isinstance(width, int) or width < 4:
        raise InputError(f"envmap width must be an integer >= 4, got {width!r}")
    img = sh_to_latlong(coeffs, width, width // 2 + 1)
    bitmap = mi.Bitmap(np.ascontiguousarray(img), mi.Bitmap.PixelFormat.RGB)
    return {"type": "envmap", "bitmap": bitmap, "scale": float(scale)}

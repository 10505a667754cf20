"""Tests for mcdenoise/eval/metrics.py: hand-computable values, pinned values, edge cases."""

from __future__ import annotations

import math
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import torch

from mcdenoise.errors import InputError, McdenoiseError
from mcdenoise.eval import metrics as M


def const(value: float, h: int = 4, w: int = 5) -> np.ndarray:
    return np.full((3, h, w), value, dtype=np.float64)


def pinned_pair() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(1234)
    ref = rng.gamma(2.0, 0.5, size=(3, 16, 16))
    out = ref + 0.1 * rng.standard_normal((3, 16, 16))
    return out, ref


# --- hand-computable values -------------------------------------------------------------------


def test_relmse_of_constant_offset():
    # (1.5 - 1)^2 / (1^2 + 0.01) everywhere
    assert M.relmse(const(1.5), const(1.0)) == pytest.approx(0.25 / 1.01, rel=1e-15)


def test_relmse_is_relative_to_the_reference_not_the_output():
    # same absolute error 0.5, reference 2 -> 0.25 / 4.01; swapping the roles changes it
    assert M.relmse(const(2.5), const(2.0)) == pytest.approx(0.25 / 4.01, rel=1e-15)
    assert M.relmse(const(2.0), const(2.5)) == pytest.approx(0.25 / 6.26, rel=1e-15)


def test_smape_and_mse_hand_values():
    assert M.smape(const(2.0), const(1.0)) == pytest.approx(1.0 / 3.01, rel=1e-15)
    assert M.mse(const(2.0), const(1.0)) == pytest.approx(1.0, rel=1e-15)
    # mixed pixels: the mean is over pixels and channels
    x = const(1.0)
    x[0, 0, 0] = 3.0  # one channel of one pixel off by 2
    assert M.mse(x, const(1.0)) == pytest.approx(4.0 / x.size, rel=1e-15)


def test_psnr_and_ssim_are_computed_on_clamped_srgb():
    # sRGB(0.214041...) = 0.5, so against black the sRGB MSE is 0.25 -> PSNR 10 log10(4)
    lin_half = ((0.5 + 0.055) / 1.055) ** 2.4
    assert M.psnr(const(lin_half), const(0.0)) == pytest.approx(10 * math.log10(4.0), rel=1e-9)
    # HDR values above 1 clamp to the same display value: identical for PSNR and SSIM ...
    assert M.psnr(const(5.0), const(2.0)) == math.inf
    assert M.ssim(const(5.0), const(2.0)) == pytest.approx(1.0)
    # ... but not for the linear metrics
    assert M.relmse(const(5.0), const(2.0)) > 1.0


def test_relmse_map_mean_is_relmse():
    out, ref = pinned_pair()
    m = M.relmse_map(out, ref)
    assert m.shape == (16, 16)
    assert float(m.mean()) == pytest.approx(M.relmse(out, ref), rel=1e-12)


# --- pinned values ----------------------------------------------------------------------------

# Produced by (numpy 2.4, scikit-image 0.26, flip-evaluator 1.7):
#   python -c "import numpy as np; from mcdenoise.eval import metrics as M; \
#     rng = np.random.default_rng(1234); ref = rng.gamma(2.0, 0.5, size=(3, 16, 16)); \
#     out = ref + 0.1 * rng.standard_normal((3, 16, 16)); \
#     print({n: m.fn(out, ref) for n, m in M.METRICS.items()})"
PINNED = {
    "relmse": (0.059999077580842775, 1e-12),
    "smape": (0.08018368614390951, 1e-12),
    "mse": (0.010634786340374909, 1e-12),
    "psnr": (22.750013877537295, 1e-10),
    "ssim": (0.9418393281049481, 1e-8),
    "flip": (0.1294119656085968, 1e-4),
}


@pytest.mark.parametrize("name", list(PINNED))
def test_pinned_values(name):
    if name == "flip" and M.flip_status() is not None:
        pytest.skip(M.flip_status())
    out, ref = pinned_pair()
    value, rel = PINNED[name]
    fn = getattr(M, name)
    assert fn(out, ref) == pytest.approx(value, rel=rel)


def test_torch_and_float32_inputs_agree_with_float64_numpy():
    out, ref = pinned_pair()
    for name in ("relmse", "smape", "mse", "psnr", "ssim"):
        fn = getattr(M, name)
        exact = fn(out, ref)
        assert fn(torch.from_numpy(out), torch.from_numpy(ref)) == pytest.approx(exact, rel=1e-12)
        assert fn(out.astype(np.float32), ref.astype(np.float32)) == pytest.approx(exact, rel=1e-5)


# --- edge cases (docs/hard-cases.md items 30-32) --------------------------------------------------------------


def test_identical_images():
    _, ref = pinned_pair()
    assert M.relmse(ref, ref) == 0.0
    assert M.smape(ref, ref) == 0.0
    assert M.mse(ref, ref) == 0.0
    assert M.psnr(ref, ref) == math.inf
    assert M.ssim(ref, ref) == pytest.approx(1.0)
    if M.flip_status() is None:
        assert M.flip(ref, ref) == 0.0


def test_zero_reference_pixels_give_defined_values():
    zero = const(0.0)
    assert M.relmse(const(0.1), zero) == pytest.approx(0.01 / 0.01)
    assert M.smape(zero, zero) == 0.0  # docs/hard-cases.md item 26: prediction = target = 0 -> 0
    assert M.smape(const(0.1), zero) == pytest.approx(0.1 / 0.11)
    values = M.compute_metrics(const(0.1), zero, ["relmse", "smape", "mse", "psnr", "ssim"])
    assert not values.failed
    assert all(math.isfinite(v) for v in values.values.values())


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_nonfinite_output_fails_and_counts_pixels(bad):
    out, ref = pinned_pair()
    out = out.copy()
    out[0, 2, 3] = bad
    out[2, 2, 3] = bad  # same pixel, another channel: still one bad pixel
    out[1, 9, 9] = bad
    values = M.compute_metrics(out, ref, output_name="den.exr")
    assert values.failed
    assert values.bad_pixels == 2
    assert "2 non-finite pixel" in values.reason and "den.exr" in values.reason
    assert all(v is None for v in values.values.values())
    # the plain functions never return a silently better (finite) mean either
    for name in ("relmse", "smape", "mse", "psnr", "ssim"):
        assert not math.isfinite(getattr(M, name)(out, ref)), name


def test_nonfinite_reference_fails_every_output():
    out, ref = pinned_pair()
    ref = ref.copy()
    ref[1, 0, 0] = math.nan
    values = M.compute_metrics(out, ref, reference_name="ref.exr")
    assert values.failed and values.bad_pixels == 0
    assert "ref.exr" in values.reason


@pytest.mark.parametrize(
    "shape",
    [(3, 16, 15), (3, 15, 16), (3, 1, 16), (3, 16, 1), (1, 16, 16)],
    ids=["narrower", "shorter", "broadcastable-rows", "broadcastable-cols", "one-channel"],
)
def test_shape_mismatch_is_an_input_error_naming_both(shape):
    _, ref = pinned_pair()
    other = np.ones(shape)
    with pytest.raises(InputError) as err:
        M.compute_metrics(other, ref, output_name="a/out.exr", reference_name="ref/cornell.exr")
    msg = str(err.value)
    if shape[0] == 3:
        assert "a/out.exr" in msg and "ref/cornell.exr" in msg
        assert f"{shape[2]}x{shape[1]}" in msg and "16x16" in msg
    assert "\n" not in msg
    with pytest.raises(McdenoiseError):
        M.relmse(other, ref)


def test_transposed_image_is_not_accepted():
    out, _ = pinned_pair()
    with pytest.raises(InputError):
        M.mse(out[:, :, :8], np.ones((3, 8, 16)))


@pytest.mark.parametrize("hw", [(1, 1), (1, 2), (2, 1), (2, 2), (3, 5), (6, 6), (7, 7)])
def test_ssim_on_tiny_images(hw):
    h, w = hw
    rng = np.random.default_rng(h * 10 + w)
    ref = rng.random((3, h, w))
    out = np.clip(ref + 0.2 * rng.standard_normal((3, h, w)), 0, 1)
    win = M.ssim_window(h, w)
    assert win % 2 == 1 and win <= min(h, w, 7)
    value = M.ssim(out, ref)
    assert math.isfinite(value) and -1.0 <= value <= 1.0
    assert M.ssim(ref, ref) == pytest.approx(1.0)


def test_ssim_prefers_the_less_noisy_output():
    _, ref = pinned_pair()
    ref = ref / ref.max()
    rng = np.random.default_rng(5)
    small = ref + 0.02 * rng.standard_normal(ref.shape)
    large = ref + 0.2 * rng.standard_normal(ref.shape)
    assert M.ssim(small, ref) > M.ssim(large, ref)
    assert M.psnr(small, ref) > M.psnr(large, ref)
    assert M.relmse(small, ref) < M.relmse(large, ref)


# --- FLIP -------------------------------------------------------------------------------------


def test_flip_black_reference_is_unavailable_not_a_crash():
    """flip_evaluator calls C++ exit(-1) on a black reference; run in a child so a regression
    shows as a failed test instead of killing pytest."""
    if M.flip_status() is not None:
        pytest.skip(M.flip_status())
    code = textwrap.dedent(
        """
        import numpy as np
        from mcdenoise.eval import metrics as M
        for v in (0.0, 1e-30):
            try:
                M.flip(np.ones((3, 8, 8)), np.full((3, 8, 8), v))
            except M.MetricUnavailable as err:
                print("unavailable:", err)
        r = M.compute_metrics(np.ones((3, 8, 8)), np.zeros((3, 8, 8)), ["relmse", "flip"])
        print("rest:", r.values["relmse"], sorted(r.unavailable))
        """
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.count("unavailable: reference is black") == 2, proc.stdout
    assert "rest: 100.0 ['flip']" in proc.stdout


def test_flip_sys_exit_is_caught_and_silent(monkeypatch, capsys):
    flip_evaluator = pytest.importorskip("flip_evaluator")

    def exits(*args, **kwargs):
        print("Invalid input.\nExiting.")
        sys.exit(1)

    monkeypatch.setattr(flip_evaluator, "evaluate", exits)
    out, ref = pinned_pair()
    with pytest.raises(M.MetricUnavailable, match=r"Invalid input\. Exiting\."):
        M.flip(out, ref)
    values = M.compute_metrics(out, ref)
    assert values.values["flip"] is None and "Exiting" in values.unavailable["flip"]
    assert values.values["relmse"] == pytest.approx(PINNED["relmse"][0])
    assert capsys.readouterr().out == ""


def test_flip_missing_package_is_reported(monkeypatch):
    monkeypatch.setitem(sys.modules, "flip_evaluator", None)  # import now raises ImportError
    assert "not installed" in M.flip_status()
    out, ref = pinned_pair()
    values = M.compute_metrics(out, ref)
    assert not values.failed
    assert values.values["flip"] is None and "not installed" in values.unavailable["flip"]
    assert values.values["ssim"] == pytest.approx(PINNED["ssim"][0])


# --- registry ---------------------------------------------------------------------------------


def test_registry_describes_every_metric():
    assert list(M.METRICS) == [
        "relmse",
        "smape",
        "mse",
        "psnr",
        "ssim",
        "flip",
        "bias",
        "bias_r",
        "bias_g",
        "bias_b",
    ]
    for name, metric in M.METRICS.items():
        d = metric.describe()
        assert d["definition"] and d["space"] and d["label"], name
    assert M.METRICS["relmse"].epsilon == 0.01 and "ε = 0.01" in M.METRICS["relmse"].definition
    assert M.METRICS["smape"].epsilon == 0.01 and "ε = 0.01" in M.METRICS["smape"].definition
    assert M.METRICS["psnr"].space.startswith("sRGB") and M.METRICS["psnr"].higher_is_better
    assert M.METRICS["mse"].space == M.LINEAR and not M.METRICS["mse"].higher_is_better


def test_resolve_metrics():
    assert M.resolve_metrics(None) == list(M.METRICS)
    assert M.resolve_metrics(["PSNR", "relmse", "psnr"]) == ["psnr", "relmse"]
    with pytest.raises(InputError, match="unknown metric 'lpips'"):
        M.resolve_metrics(["lpips"])
    with pytest.raises(InputError):
        M.compute_metrics(const(1.0), const(1.0), ["nope"])


def test_compute_metrics_subset_only_computes_requested():
    out, ref = pinned_pair()
    values = M.compute_metrics(out, ref, ["mse"])
    assert list(values.values) == ["mse"]
    assert values.values["mse"] == pytest.approx(PINNED["mse"][0])


@pytest.mark.parametrize("shape", [(16, 16), (4, 16, 16), (1, 3, 16, 16)])
def test_non_rgb_layouts_are_rejected(shape):
    with pytest.raises(InputError, match=r"\(3, H, W\)"):
        M.relmse(np.ones(shape), np.ones(shape))


def test_values_beyond_float32_do_not_break_flip_or_warn():
    values = M.compute_metrics(const(1e39), const(1.0))
    assert not values.failed
    assert values.values["relmse"] == pytest.approx((1e39 - 1) ** 2 / 1.01)
    assert values.values["psnr"] == math.inf  # both clamp to white in sRGB
    if M.flip_status() is None:
        assert values.values["flip"] is None and "float32" in values.unavailable["flip"]


# --- mean bias (issue 20 item 7) ----------------------------------------------------------------

# Produced by the command of PINNED above, printing the bias entries of M.METRICS.
PINNED_BIAS = {
    "bias": -0.009439116447282386,
    "bias_r": -0.005031453070785075,
    "bias_g": -0.0032032073865783596,
    "bias_b": -0.019988264138270817,
}


def test_mean_bias_hand_values():
    # 3 % less energy everywhere -> -0.03; 10 % more in R only -> R +0.1, summary +0.1 / 3
    assert M.mean_bias(const(0.97), const(1.0)) == pytest.approx(-0.03, abs=1e-15)
    x = const(1.0)
    x[0] = 1.1
    assert M.channel_bias(x, const(1.0)) == pytest.approx((0.1, 0.0, 0.0), abs=1e-15)
    assert M.mean_bias(x, const(1.0)) == pytest.approx(0.1 / 3, abs=1e-15)
    # a mean, not a pixelwise error: errors that cancel give no bias (but a relMSE)
    y = const(1.0)
    y[:, 0, 0], y[:, 0, 1] = 1.5, 0.5
    assert M.mean_bias(y, const(1.0)) == pytest.approx(0.0, abs=1e-15)
    assert M.relmse(y, const(1.0)) > 0
    # the summary weighs channels by their energy: 10 % darker in a channel twice as bright
    ref = const(1.0)
    ref[1] = 2.0
    out = ref.copy()
    out[1] = 1.8
    assert M.mean_bias(out, ref) == pytest.approx(-0.2 / 4.0, abs=1e-15)


def test_mean_bias_pinned_and_registered():
    out, ref = pinned_pair()
    values = M.compute_metrics(out, ref, ["bias"])
    assert list(values.values) == ["bias", "bias_r", "bias_g", "bias_b"]  # bias brings R, G, B
    for name, pinned in PINNED_BIAS.items():
        assert values.values[name] == pytest.approx(pinned, rel=1e-12), name
    assert M.mean_bias(out, ref) == pytest.approx(PINNED_BIAS["bias"], rel=1e-12)
    assert M.METRICS["bias"].signed and M.METRICS["bias_g"].part_of == "bias"
    assert M.METRICS["bias"].describe()["best"] == "closest to 0"
    # closest to 0 is best, whatever the sign
    assert M.METRICS["bias"].better(0.01, -0.02) and M.METRICS["bias"].better(-0.01, 0.02)
    assert M.METRICS["relmse"].better(0.1, 0.2) and M.METRICS["psnr"].better(30.0, 20.0)
    # float32 and torch inputs: the same numbers
    t = M.mean_bias(torch.from_numpy(out), torch.from_numpy(ref))
    assert t == pytest.approx(PINNED_BIAS["bias"], rel=1e-12)


def test_mean_bias_of_a_zero_reference_mean():
    zero = const(0.0)
    assert M.mean_bias(zero, zero) == 0.0  # nothing against nothing: no bias
    with pytest.raises(M.MetricUnavailable, match="reference's mean is 0"):
        M.mean_bias(const(0.1), zero)
    # one black channel: only that channel is unavailable, with its reason
    ref = const(1.0)
    ref[2] = 0.0
    out = const(1.0)
    out[2] = 0.5
    values = M.compute_metrics(out, ref, ["bias"])
    assert not values.failed
    assert values.values["bias_r"] == 0.0 and values.values["bias_b"] is None
    assert "mean in B is 0" in values.unavailable["bias_b"]
    assert values.values["bias"] == pytest.approx(0.5 / 2.0)
    # a negative reference mean (possible with negative lobes): relative to its magnitude
    assert M.mean_bias(const(-0.5), const(-1.0)) == pytest.approx(0.5)


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_mean_bias_with_nonfinite_pixels(bad):
    out = const(1.0)
    out[1, 2, 3] = bad
    # the plain function does not hide it ...
    assert not math.isfinite(M.mean_bias(out, const(1.0)))
    assert not math.isfinite(M.channel_bias(out, const(1.0))[1])
    # ... and compute_metrics fails the output, as for every metric
    values = M.compute_metrics(out, const(1.0), ["relmse", "bias"])
    assert values.failed and values.bad_pixels == 1
    assert values.values == dict.fromkeys(["relmse", "bias", "bias_r", "bias_g", "bias_b"])
